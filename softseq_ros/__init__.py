"""softseq_ros: an emulated rig for soft actuators with a hardware-encoded inflation sequence."""

__version__ = '0.1.0'
