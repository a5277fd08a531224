"""
Parameters of the rig's nodes: declared with descriptors, checked with a reason that names them.

Every rig node derives from :class:`ParameterNode`, which declares its parameters with
descriptors (description, range, read-only) and validates every value, at start and at run
time, in one set-parameters callback that answers with a reason naming the parameter
(``rate_hz: must be > 0, got 0``). Rates accept integers and doubles (``-p rate_hz:=100``).
"""

from dataclasses import dataclass
import math
from typing import Any, Callable, Sequence

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from softseq_ros.errors import UserError
from softseq_ros.rig.contract import OUTPUT_NAMES
from softseq_ros.scene.limits import Limit
from softseq_ros.scene.loader import Scene, load_scene


class NodeConfigError(UserError):
    """A node configuration that cannot run; the message names the parameter."""


def outputs_reason(value: list[str]) -> str | None:
    """Why an ``outputs`` parameter is refused (an unknown output name), or None."""
    unknown = [name for name in value if name not in OUTPUT_NAMES]
    if unknown:
        return (f'unknown output(s) {", ".join(unknown)}; expected some of '
                f'{", ".join(OUTPUT_NAMES)}')
    return None


@dataclass(frozen=True)
class _Rule:
    """How a declared parameter's values are checked."""

    kind: str  # 'float', 'int', 'str', 'bool', 'str_array', 'float_array'
    minimum: float | None = None
    maximum: float | None = None
    open_minimum: bool = False
    check: Callable[[Any], str | None] | None = None

    def reason(self, parameter: Parameter) -> str | None:
        """Why ``parameter`` is refused, or None when it is fine."""
        value = parameter.value
        kind = parameter.type_
        if kind == Parameter.Type.NOT_SET:
            return None  # declared without a value (an empty list): nothing to check
        if self.kind == 'float':
            if kind not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER):
                return f'must be a number (integer or double), got {kind.name.lower()} {value!r}'
            value = float(value)
            if not math.isfinite(value):
                return f'must be finite, got {value}'
        elif self.kind == 'int':
            if kind != Parameter.Type.INTEGER:
                return f'must be an integer, got {kind.name.lower()} {value!r}'
        elif self.kind == 'str' and kind != Parameter.Type.STRING:
            return f'must be a string, got {kind.name.lower()} {value!r}'
        elif self.kind == 'bool' and kind != Parameter.Type.BOOL:
            return f'must be true or false, got {kind.name.lower()} {value!r}'
        elif self.kind == 'str_array' and kind != Parameter.Type.STRING_ARRAY:
            return f'must be a list of strings, got {kind.name.lower()} {value!r}'
        elif self.kind == 'float_array':
            if kind not in (Parameter.Type.DOUBLE_ARRAY, Parameter.Type.INTEGER_ARRAY):
                return f'must be a list of numbers, got {kind.name.lower()} {value!r}'
            if not all(math.isfinite(float(x)) for x in value):
                return 'must hold finite numbers only'
        if self.kind in ('float', 'int'):
            reason = Limit(self.minimum, self.maximum, self.open_minimum).reason(value)
            if reason is not None:
                return reason
        if self.check is not None:
            return self.check(value)
        return None


class ParameterNode(Node):
    """A node whose parameters carry descriptors and are validated with a reason."""

    def __init__(self, node_name: str, **node_kwargs: Any) -> None:
        """Create the node (keywords go to rclpy's Node) and install the validation."""
        super().__init__(node_name, **node_kwargs)
        self._rules: dict[str, _Rule] = {}
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._post_set)
        # Declarations run the callbacks too; changes apply only once the node is built.
        self.configured = False

    def _declare(self, name: str, default: Any, descriptor: ParameterDescriptor,
                 rule: _Rule) -> Any:
        self._rules[name] = rule
        descriptor.name = name
        return self.declare_parameter(name, default, descriptor).value

    def declare_number(self, name: str, default: float, description: str, *,
                       minimum: float | None = None, maximum: float | None = None,
                       open_minimum: bool = False, read_only: bool = False) -> float:
        """Declare a double that also accepts integers (``-p rate_hz:=100``); return it."""
        descriptor = ParameterDescriptor(
            type=ParameterType.PARAMETER_DOUBLE, description=description,
            read_only=read_only, dynamic_typing=True,
            additional_constraints=_bounds_text(minimum, maximum, open_minimum)
            + '; integer or double')
        if minimum is not None and maximum is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(minimum), to_value=float(maximum), step=0.0)]
        value = self._declare(name, float(default), descriptor,
                              _Rule('float', minimum, maximum, open_minimum))
        return float(value)

    def declare_integer(self, name: str, default: int, description: str, *,
                        minimum: int | None = None, maximum: int | None = None,
                        read_only: bool = False) -> int:
        """Declare an integer parameter with an IntegerRange; return it."""
        descriptor = ParameterDescriptor(
            type=ParameterType.PARAMETER_INTEGER, description=description,
            read_only=read_only, additional_constraints=_bounds_text(minimum, maximum, False))
        if minimum is not None:
            descriptor.integer_range = [IntegerRange(
                from_value=int(minimum), to_value=int(maximum if maximum is not None
                                                      else 2 ** 31 - 1), step=0)]
        return int(self._declare(name, int(default), descriptor, _Rule('int', minimum, maximum)))

    def declare_text(self, name: str, default: str, description: str, *,
                     read_only: bool = False,
                     check: Callable[[Any], str | None] | None = None) -> str:
        """Declare a string parameter; ``check(value)`` returns a reason to refuse it."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_STRING,
                                         description=description, read_only=read_only)
        return str(self._declare(name, default, descriptor, _Rule('str', check=check)))

    def declare_flag(self, name: str, default: bool, description: str, *,
                     read_only: bool = False) -> bool:
        """Declare a boolean parameter; return it."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_BOOL,
                                         description=description, read_only=read_only)
        return bool(self._declare(name, bool(default), descriptor, _Rule('bool')))

    def declare_texts(self, name: str, default: Sequence[str], description: str, *,
                      read_only: bool = False,
                      check: Callable[[Any], str | None] | None = None) -> list[str]:
        """Declare a string-array parameter; return it."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_STRING_ARRAY,
                                         description=description, read_only=read_only)
        return list(self._declare(name, list(default), descriptor,
                                  _Rule('str_array', check=check)))

    def declare_numbers(self, name: str, default: Sequence[float], description: str, *,
                        read_only: bool = False,
                        check: Callable[[Any], str | None] | None = None) -> list[float]:
        """Declare a double-array parameter; return it as floats ([] when unset)."""
        descriptor = ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                         description=description, read_only=read_only)
        # An empty list has no element type; rclpy declares it from the type alone (unset).
        value = self._declare(name, [float(x) for x in default] or Parameter.Type.DOUBLE_ARRAY,
                              descriptor, _Rule('float_array', check=check))
        return [float(x) for x in (value or [])]

    def declare_scene(self) -> Scene:
        """Declare the read-only ``scene`` parameter and load the scene it names."""
        name = self.declare_text(
            'scene', 'paper', 'Scene file path or shipped scene name; it gives the defaults '
            'of the other parameters.', read_only=True)
        return load_scene(name)

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            rule = self._rules.get(parameter.name)
            if rule is None:
                continue
            reason = rule.reason(parameter)
            if reason is not None:
                return SetParametersResult(successful=False,
                                           reason=f'{parameter.name}: {reason}')
        return SetParametersResult(successful=True)

    def _post_set(self, parameters: list[Parameter]) -> None:
        if self.configured:
            self._parameters_changed(parameters)

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        """Apply accepted changes; nodes override this for their dynamic parameters."""


def _bounds_text(minimum: float | None, maximum: float | None, open_minimum: bool) -> str:
    parts = []
    if minimum is not None:
        parts.append(f'{">" if open_minimum else ">="} {minimum:g}')
    if maximum is not None:
        parts.append(f'<= {maximum:g}')
    return ' and '.join(parts) if parts else 'any value'
