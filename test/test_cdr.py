"""The fast CDR encoders against rclpy's own (de)serialisation of the same messages."""

from geometry_msgs.msg import Point, Pose, PoseArray
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import FluidPressure, Image, JointState
from std_msgs.msg import ColorRGBA, String
from visualization_msgs.msg import Marker, MarkerArray, UVCoordinate

from softseq_ros.bag.cdr import ENCODERS, encode
from softseq_ros.bag.writer import message_type_name, serialize


def stamped(msg, sec=1_795_000_000, nanosec=123_456_789, frame='softseq_base'):
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.header.frame_id = frame
    return msg


def pose(i):
    p = Pose(position=Point(x=0.1 * i, y=-1e-3 * i, z=1e300 if i == 3 else 0.5))
    p.orientation.y, p.orientation.w = -0.2, 0.98
    return p


MESSAGES = [
    stamped(JointState(name=['syringe'], position=[6.5e-5], velocity=[5e-8])),
    stamped(JointState(name=['bottom', 'top', 'tip'], position=[1e-6, 2.5e-5, 3.0],
                       effort=[9069.0, 9069.0, -1.5])),
    stamped(JointState(name=[], position=[], velocity=[], effort=[]), frame=''),
    stamped(JointState(name=['ä_unicode', 'b'], position=[float('inf'), -0.0])),
    stamped(FluidPressure(fluid_pressure=110394.25, variance=0.0)),
    stamped(PoseArray(poses=[pose(i) for i in range(41)])),
    stamped(PoseArray(poses=[])),
    String(data=''),
    String(data='{"injected_m3": 2.6e-05, "from_volumes_m3": [1e-06, 2e-06]}'),
    stamped(Image(height=3, width=5, encoding='rgb8', is_bigendian=0, step=15,
                  data=bytes(range(45)))),
    MarkerArray(markers=[
        stamped(Marker(ns='backbone', id=7, type=Marker.LINE_STRIP, action=Marker.ADD,
                       points=[Point(x=0.01 * i, z=-0.02 * i) for i in range(21)],
                       color=ColorRGBA(r=0.25, g=0.5, b=0.75, a=1.0),  # float32-exact
                       colors=[ColorRGBA(r=1.0), ColorRGBA(b=0.5)],
                       uv_coordinates=[UVCoordinate(u=0.25, v=0.75)],
                       text='segment', mesh_resource='package://x', frame_locked=True,
                       mesh_use_embedded_materials=True)),
        Marker(),
    ]),
]


@pytest.mark.parametrize('msg', MESSAGES, ids=lambda m: type(m).__name__)
def test_encoding_decodes_to_the_same_message_in_rclpy(msg):
    type_name = message_type_name(msg)
    data = encode(msg, type_name)
    assert data is not None
    assert deserialize_message(data, type(msg)) == msg
    # Same length as what DDS carries once Fast DDS's trailing slack is cut.
    assert len(data) == len(serialize(msg))


@pytest.mark.parametrize('msg', MESSAGES, ids=lambda m: type(m).__name__)
def test_padding_is_zero_so_bags_are_deterministic(msg):
    type_name = message_type_name(msg)
    assert encode(msg, type_name) == encode(msg, type_name)


def test_every_rig_type_has_an_encoder():
    from softseq_ros.nodes.common import TOPICS
    rig_types = {message_type_name(spec.msg_type()) for topic, spec in TOPICS.items()
                 if topic != '/clock'}
    assert rig_types <= set(ENCODERS)


def test_unknown_types_fall_back():
    from builtin_interfaces.msg import Time
    assert encode(Time(), 'builtin_interfaces/msg/Time') is None
