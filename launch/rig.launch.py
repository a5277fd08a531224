"""
A rig on a ROS 2 Jazzy install: syringe pump, actuator, camera and recorder in one namespace.

    ros2 launch softseq_ros rig.launch.py namespace:=rig2 scene:=fig1_asymmetric

Every node runs in ``namespace`` (topics ``/<namespace>/pump/command`` and so on, services
``/<namespace>/syringe_pump/start``) with the scene ``scene`` (a shipped name or a YAML file).
The pump waits for ``~/start`` unless ``autostart:=true``, so the recorder has found every
topic before the first command; ``output`` names the bag folder (empty: bags/rig_<UTC time>).
Launch arguments: namespace, scene, autostart, output.
"""

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    """The pump, actuator, camera and recorder nodes of one rig."""
    namespace = LaunchConfiguration('namespace')
    scene = LaunchConfiguration('scene')
    autostart = ParameterValue(LaunchConfiguration('autostart'), value_type=bool)
    output = ParameterValue(LaunchConfiguration('output'), value_type=str)
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='rig1',
                              description='Namespace of every node, topic and service.'),
        DeclareLaunchArgument('scene', default_value='paper',
                              description='Scene file path or shipped scene name.'),
        DeclareLaunchArgument('autostart', default_value='false',
                              description='Start the programme at once (else call '
                                          '~/start once the recorder is up).'),
        DeclareLaunchArgument('output', default_value='',
                              description='Bag folder of the recorder; empty: '
                                          'bags/rig_<UTC time>.'),
        Node(package='softseq_ros', executable='syringe_pump', name='syringe_pump',
             namespace=namespace, output='screen',
             parameters=[{'scene': scene, 'autostart': autostart}]),
        Node(package='softseq_ros', executable='actuator', name='actuator',
             namespace=namespace, output='screen', parameters=[{'scene': scene}]),
        Node(package='softseq_ros', executable='camera', name='camera',
             namespace=namespace, output='screen', parameters=[{'scene': scene}]),
        Node(package='softseq_ros', executable='recorder', name='recorder',
             namespace=namespace, output='screen', parameters=[{'output': output}]),
    ])
