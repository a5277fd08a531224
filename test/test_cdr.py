"""The fast CDR encoders against rclpy's own (de)serialisation of the same messages."""

from geometry_msgs.msg import Point, Pose, PoseArray
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import FluidPressure, Image, JointState
from std_msgs.msg import ColorRGBA, String
from visualization_msgs.msg import Marker, MarkerArray, UVCoordinate

from softseq_ros.bag.forms import message_type_name, serialize
from softseq_ros.wire.cdr import ENCODERS, FixedLayout, encode


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
    from softseq_ros.wire import contract
    assert {topic.type_name for topic in contract.RIG_TOPICS} <= set(ENCODERS)


def test_unknown_types_fall_back():
    from builtin_interfaces.msg import Time
    assert encode(Time(), 'builtin_interfaces/msg/Time') is None


def test_fixed_layout_restamps_and_refills_a_pose_array():
    layout = FixedLayout(stamped(PoseArray(poses=[Pose() for _ in range(41)])),
                         'geometry_msgs/msg/PoseArray')
    values = np.random.default_rng(3).normal(size=(41, 7))
    stamp = 1_795_000_123 * 10**9 + 987_654_321
    decoded = deserialize_message(layout.encode(stamp, [values]), PoseArray)
    expected = stamped(PoseArray(poses=[
        Pose(position=Point(x=v[0], y=v[1], z=v[2])) for v in values]),
        sec=1_795_000_123, nanosec=987_654_321)
    for pose_msg, v in zip(expected.poses, values):
        o = pose_msg.orientation
        o.x, o.y, o.z, o.w = v[3:]
    assert decoded == expected


def test_fixed_layout_restamps_every_marker_but_not_the_texture_header():
    example = MESSAGES[-1]
    layout = FixedLayout(example, 'visualization_msgs/msg/MarkerArray')
    assert layout.block_sizes == (21 * 24,)
    points = np.arange(63, dtype=float).reshape(21, 3)
    decoded = deserialize_message(layout.encode(5 * 10**9 + 7, [points]), MarkerArray)
    marker, empty = decoded.markers
    assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (5, 7)
    assert (empty.header.stamp.sec, empty.header.stamp.nanosec) == (5, 7)
    assert (marker.texture.header.stamp.sec, marker.texture.header.stamp.nanosec) == (0, 0)
    assert [(p.x, p.y, p.z) for p in marker.points] == [tuple(r) for r in points.tolist()]
    # Everything else stays as in the example.
    marker.header, marker.points = example.markers[0].header, example.markers[0].points
    assert marker == example.markers[0]


def test_fixed_layout_refuses_blocks_of_another_shape():
    layout = FixedLayout(PoseArray(poses=[Pose() for _ in range(3)]),
                         'geometry_msgs/msg/PoseArray')
    with pytest.raises(ValueError, match='block of 112 bytes where the layout holds 168'):
        layout.encode(0, [np.zeros((2, 7))])
    with pytest.raises(ValueError, match='expected 1 blocks, got 2'):
        layout.encode(0, [np.zeros((3, 7)), np.zeros((3, 7))])


def test_the_rig_values_encode_byte_for_byte_as_rclpy_serialises_the_messages():
    # The wire encoders (what nodes publish and batch bags hold) against rclpy's own
    # serialisation of the same message built field by field.
    from softseq_ros.wire import values
    from softseq_ros.wire.payloads import MARKER_WIDTH_M
    from softseq_ros.wire.payloads import encode as encode_value

    sec, nanosec = 1_795_000_123, 456_789
    stamp = sec * 10**9 + nanosec
    names = ('bottom', 'top')

    def header(msg, frame=''):
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.header.frame_id = frame
        return msg

    poses = np.random.default_rng(5).normal(size=(41, 7))
    pose_msg = header(PoseArray(poses=[Pose() for _ in range(41)]), 'softseq_base')
    for p, row in zip(pose_msg.poses, poses):
        (p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
         p.orientation.z, p.orientation.w) = row.tolist()
    lines = [poses[:21, :3], poses[20:, :3]]
    marker_msg = MarkerArray(markers=[
        header(Marker(ns='backbone', id=i, type=Marker.LINE_STRIP, action=Marker.ADD,
                      points=[Point(x=x, y=y, z=z) for x, y, z in line.tolist()],
                      color=ColorRGBA(r=rgb[0] / 255.0, g=rgb[1] / 255.0, b=rgb[2] / 255.0,
                                      a=1.0)), 'softseq_base')
        for i, (line, rgb) in enumerate(zip(lines, ((31, 119, 180), (255, 127, 14))))])
    for marker in marker_msg.markers:
        marker.pose.orientation.w = 1.0
        marker.scale.x = MARKER_WIDTH_M
    cases = [
        (values.PumpCommand(stamp, 2.5e-5, -5e-8),
         header(JointState(name=['syringe'], position=[2.5e-5], velocity=[-5e-8]))),
        (values.PumpSetpoint(stamp, injected_m3=1.5e-5),
         header(JointState(name=['syringe'], position=[1.5e-5]))),
        (values.PumpSetpoint(stamp, flow_m3_per_s=-2e-7),
         header(JointState(name=['syringe'], velocity=[-2e-7]))),
        (values.PumpSetpoint(stamp, gauge_pa=5000.0),
         header(JointState(name=['syringe'], effort=[5000.0]))),
        (values.Pressure(stamp, 110394.25), header(FluidPressure(fluid_pressure=110394.25))),
        (values.SegmentVolumes(stamp, names, [1e-5, 3e-5], 9069.5),
         header(JointState(name=list(names), position=[1e-5, 3e-5], effort=[9069.5] * 2))),
        (values.SegmentCurvatures(stamp, names, [0.5, -12.0]),
         header(JointState(name=list(names), position=[0.5, -12.0]))),
        (values.ChannelFlows(stamp, ('bottom_to_top', 'top_to_tip'), [2.5e-6, -1e-9],
                             [812.5, -0.25]),
         header(JointState(name=['bottom_to_top', 'top_to_tip'], velocity=[2.5e-6, -1e-9],
                           effort=[812.5, -0.25]))),
        (values.PumpStatus(stamp, 'stopped', 'requested'),
         String(data='{"state": "stopped", "reason": "requested", "stamp_ns": %d}' % stamp)),
        (values.SceneIdentity(stamp, 'paper', names, 'ab' * 32),
         String(data='{"scene": "paper", "segments": ["bottom", "top"], "segments_sha256": '
                     '"%s", "stamp_ns": %d}' % ('ab' * 32, stamp))),
        (values.Backbone(stamp, poses), pose_msg),
        (values.Snapshot(stamp, poses), pose_msg),
        (values.Markers(stamp, lines), marker_msg),
        (values.SideImage(stamp, 5, 3, bytes(range(45))),
         header(Image(height=3, width=5, encoding='rgb8', is_bigendian=0, step=15,
                      data=bytes(range(45))), 'softseq_base')),
    ]
    for value, msg in cases:
        assert encode_value(value) == serialize(msg), type(value).__name__
    # Every topic value type is covered, or named here as JSON text checked elsewhere.
    covered = {type(value) for value, _ in cases} | {values.SnapThrough, values.SnapshotStep}
    assert covered == set(values.TOPIC_VALUE_TYPES)
