"""
What the ``ros2`` command gives, for an install of the PyPI wheels that has no ``ros2``.

``softseq ros call``, ``param``, ``lifecycle`` and ``echo`` reach running nodes through their
services and topics with public rclpy APIs only; ``softseq ros rig`` starts a whole rig with
its recorder in a namespace, as ``launch/rig.launch.py`` does. Each waits a bounded time for
what it needs and says what it did not find (softseq_ros.ros_tools.session).
"""
