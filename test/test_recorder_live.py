"""The recorder node in this process over DDS: parameter services, topic choice, splitting."""

from pathlib import Path

import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from softseq_ros.nodes.recorder import RIG_TOPICS, Recorder
from softseq_ros.testing import spinning, wait_for

pytestmark = pytest.mark.ros


def _get(node: Node, service: str, names: list[str]) -> list:
    client = node.create_client(GetParameters, service)
    assert client.wait_for_service(timeout_sec=15.0)
    future = client.call_async(GetParameters.Request(names=names))
    wait_for(future.done, f'the answer of {service}')
    return list(future.result().values)


def test_get_parameters_answers_for_a_parameter_given_no_value(context, tmp_path: Path):
    recorder = Recorder(context=context, parameter_overrides=[
        Parameter('output', value=str(tmp_path / 'bag'))])
    asker = Node('asker', context=context)
    try:
        with spinning(context, recorder, asker):
            types, = _get(asker, '/recorder/get_parameters', ['types'])
            assert types.type == ParameterType.PARAMETER_NOT_SET
            values = _get(asker, '/recorder/get_parameters', ['topics', 'types', 'compression'])
            assert [v.type for v in values] == [ParameterType.PARAMETER_STRING_ARRAY,
                                                ParameterType.PARAMETER_NOT_SET,
                                                ParameterType.PARAMETER_STRING]
            assert list(values[0].string_array_value) == list(RIG_TOPICS)
            assert values[2].string_value == 'zstd'
    finally:
        recorder.close_bag(log=False)
    # Given, the types are read as before; a value that is no list of strings is refused.
    typed = Recorder(context=context, parameter_overrides=[
        Parameter('output', value=str(tmp_path / 'typed')),
        Parameter('topics', value=['/a']), Parameter('types', value=['std_msgs/msg/String'])])
    assert typed.get_parameter('types').value == ['std_msgs/msg/String']
    typed.close_bag(log=False)
    typed.destroy_node()
    with pytest.raises(InvalidParameterValueException, match='types: must be a list of strings'):
        Recorder(context=context, parameter_overrides=[
            Parameter('output', value=str(tmp_path / 'bad')), Parameter('types', value=5)])
