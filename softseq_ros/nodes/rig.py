"""
The whole rig in one process: syringe pump, actuator and camera nodes on one executor.

The same nodes as ``syringe_pump``, ``actuator`` and ``camera`` started one by one, composed as
ROS 2 components with intra-process communication would be: every topic is published over DDS
for the world outside, and a value between the three cores goes straight to its consumer
(softseq_ros.nodes.core_node.LocalCores), so a pump command reaches the actuator, and its state
the camera, within the pump's tick. The actuator therefore hears only this process's pump: to
drive it from another pump, start the nodes as separate processes.

``--ros-args -p name:=value`` sets a parameter of every node that declares it (``scene``,
``rate_hz``); ``-p camera:rate_hz:=100`` sets it for one node; ``-r __ns:=/rig2`` moves the
whole rig, topics and services, into ``/rig2``, where ``camera:`` still names the camera (as
does its fully qualified name, ``/rig2/camera:``). A prefix that names none of the three nodes,
or a parameter none of the nodes it reaches has, is refused (softseq_ros.nodes.runner).
"""

from softseq_ros.nodes.actuator import ActuatorNode
from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.runner import run_nodes
from softseq_ros.nodes.syringe_pump import SyringePumpNode


def main(args: list[str] | None = None) -> None:
    """Run the pump, actuator and camera nodes in this process."""
    run_nodes([SyringePumpNode, ActuatorNode, CameraNode], args, 'rig')


if __name__ == '__main__':
    main()
