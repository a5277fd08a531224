"""One set of limits: a value the scene accepts, the node accepts, and the same for refusals."""

import json

import pytest
from rclpy.exceptions import InvalidParameterValueException
from rclpy.parameter import Parameter
from scenes import FAST_SCENE
import yaml

from softseq_ros.nodes.camera import CameraNode
from softseq_ros.nodes.syringe_pump import SyringePumpNode
from softseq_ros.scene.limits import LIMITS
from softseq_ros.scene.loader import SceneError, load_scene

# (node, parameter, scene section, scene key): the same setting under its two names.
SETTINGS = [
    (SyringePumpNode, 'rate_hz', 'pump', 'rate_hz'),
    (SyringePumpNode, 'flow_rate_m3_per_s', 'pump', 'flow_rate_m3_per_s'),
    (SyringePumpNode, 'cycles', 'pump', 'cycles'),
    (CameraNode, 'rate_hz', 'camera', 'rate_hz'),
    (CameraNode, 'noise_std_m', 'camera', 'noise_std_m'),
    (CameraNode, 'points_per_segment', 'camera', 'points_per_segment'),
    (CameraNode, 'width', 'camera', 'image_width_px'),
    (CameraNode, 'height', 'camera', 'image_height_px'),
]


def _scene_with(tmp_path, section, key, value):
    data = json.loads(json.dumps(FAST_SCENE))
    data.setdefault(section, {})[key] = value
    path = tmp_path / 'limits.yaml'
    path.write_text(yaml.safe_dump(data), encoding='utf-8')
    return path


def _beyond(limit, integer):
    if limit.maximum is not None:
        return limit.maximum + 1 if integer else limit.maximum * 10.0
    return None


@pytest.mark.parametrize('node_class, parameter, section, key', SETTINGS,
                         ids=[f'{s[0].__name__}-{s[1]}' for s in SETTINGS])
def test_a_scene_that_loads_also_runs_and_the_same_values_are_refused(
        context, tmp_path, node_class, parameter, section, key):
    limit = LIMITS[f'{section}.{key}']
    integer = key in ('cycles', 'points_per_segment', 'image_width_px', 'image_height_px')
    top = int(limit.maximum) if integer else limit.maximum
    # At the upper bound: the scene loads, and a node started from it keeps the value.
    scene_path = _scene_with(tmp_path, section, key, top)
    load_scene(scene_path)
    node = node_class(context=context,
                      parameter_overrides=[Parameter('scene', value=str(scene_path))])
    try:
        assert node.get_parameter(parameter).value == top
        descriptor = node.describe_parameter(parameter)
        bounds = (descriptor.integer_range or descriptor.floating_point_range)[0]
        assert (bounds.from_value, bounds.to_value) == (limit.minimum, limit.maximum)
    finally:
        node.destroy_node()
    # Beyond it: the scene names its key, the node its parameter, with the same reason.
    beyond = _beyond(limit, integer)
    with pytest.raises(SceneError) as scene_refusal:
        load_scene(_scene_with(tmp_path, section, key, beyond))
    reason = str(scene_refusal.value).split(f'{section}.{key}: ', 1)[1]
    assert reason.startswith(f'must be <= {limit.maximum:g}')
    with pytest.raises(InvalidParameterValueException) as node_refusal:
        node_class(context=context, parameter_overrides=[
            Parameter('scene', value='paper'), Parameter(parameter, value=beyond)])
    assert str(node_refusal.value) == f'/{node_class.NODE_NAME}: parameter {parameter}: {reason}'
