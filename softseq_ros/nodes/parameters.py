"""
Parameters of the rig's nodes: declared with descriptors, checked with a reason that names them.

Every rig node derives from :class:`ParameterNode`, which declares its parameters with
descriptors (description, range, read-only) and validates every value, at start and at run
time, in one set-parameters callback that answers with a reason naming the parameter
(``rate_hz: must be > 0, got 0``). Rates accept integers and doubles (``-p rate_hz:=100``).

A node's parameters on the command line (``-p node:name:=value``) are matched here, not by rcl:
rcl reads the prefix as the node's fully qualified name at the root (``syringe_pump`` is
``/syringe_pump``), so under ``-r __ns:=/rig_b`` it reaches no node, and it refuses a prefix
with a slash (``rig_b/syringe_pump``) outright. :func:`split_ros_arguments` takes these rules
out of the arguments rcl sees; a node takes those whose prefix is its name (in any namespace) or
its fully qualified name, with or without the leading slash. rcl still reads every value
(:func:`read_rules`), and the node gets them as parameter overrides, which win over a
``--params-file``. The file's keys stay rcl's: the fully qualified name
(``/rig_b/syringe_pump``), ``/**`` or a wildcard form such as ``/**/syringe_pump``.
"""

from dataclasses import dataclass
import math
import re
from typing import Any, Callable, Sequence

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.utilities import remove_ros_args

from softseq_ros.errors import UserError
from softseq_ros.rig.model import load_rig_scene
from softseq_ros.scene.limits import Limit
from softseq_ros.scene.loader import Scene
from softseq_ros.wire.contract import OUTPUT_NAMES


class NodeConfigError(UserError):
    """A node configuration that cannot run; the message names the parameter."""


class ParameterValueError(NodeConfigError, InvalidParameterValueException):
    """
    A value given to a node at start that it refuses: ``<node>: parameter <name>: <reason>``.

    Also rclpy's InvalidParameterValueException, which a node built in Python raised before.
    """

    def __init__(self, message: str) -> None:
        """The one line, as the user sees it."""
        Exception.__init__(self, message)


# rcl's ROS arguments that take a value (rcl/arguments.h), so that a value is never read as a
# flag; the others (--enable-rosout-logs, ...) stand alone.
_VALUE_FLAGS = frozenset({'-r', '--remap', '-p', '--param', '--params-file', '-e', '--enclave',
                          '--log-level', '--log-config-file', '--log-file-name'})
_PARAM_FLAGS = frozenset({'-p', '--param'})
_REMAP_FLAGS = frozenset({'-r', '--remap'})


@dataclass(frozen=True)
class ParameterRule:
    """One ``-p [node:]name:=value`` as given; ``node`` is '' for a rule for every node."""

    node: str
    name: str
    value: str

    @property
    def text(self) -> str:
        """The rule as the user typed it."""
        return f'{self.node}:{self.name}:={self.value}' if self.node else \
            f'{self.name}:={self.value}'

    def matches(self, node_name: str, fqn: str) -> bool:
        """
        True when the rule is meant for the node ``node_name`` (fully qualified: ``fqn``).

        A prefix without a slash is a node name in any namespace (what ``-p camera:rate_hz:=30``
        means to someone who also gave ``-r __ns:=/rig2``); one with a slash is a fully
        qualified name, the leading slash optional.
        """
        if not self.node:
            return True
        if '/' not in self.node:
            return self.node == node_name
        return '/' + self.node.lstrip('/') == fqn


@dataclass(frozen=True)
class RosArguments:
    """A command line split into what rcl reads and the node-prefixed parameter rules."""

    rcl_args: list[str]
    rules: list[ParameterRule]          # the node-prefixed ones, in the given order
    global_rules: list[ParameterRule]   # those for every node (left to rcl)
    remaps: list[tuple[str, str, str]]  # (node prefix or '', '__ns' or '__node', value)

    def rules_for(self, node_name: str, fqn: str) -> list[ParameterRule]:
        """The node-prefixed rules meant for this node."""
        return [rule for rule in self.rules if rule.matches(node_name, fqn)]


def _parameter_rule(text: str) -> ParameterRule | None:
    """A rule from ``[node:]name:=value``; None when it is no rule rcl would accept."""
    head, separator, value = text.partition(':=')
    if not separator:
        return None
    node, _, name = head.rpartition(':')
    return ParameterRule(node, name, value)


def split_ros_arguments(args: Sequence[str]) -> RosArguments:
    """
    Split a command line (argv or a node's cli_args) for rcl and for our node matching.

    The node-prefixed ``-p`` rules are taken out (a prefix holding an rcl wildcard stays, for
    rcl to refuse with its own words); everything else is passed on unchanged.
    """
    rcl_args: list[str] = []
    rules: list[ParameterRule] = []
    global_rules: list[ParameterRule] = []
    remaps: list[tuple[str, str, str]] = []
    in_ros_args = False
    tokens = list(args)
    index = 0
    while index < len(tokens):
        token = tokens[index]
        index += 1
        if token == '--ros-args':
            in_ros_args = True
        elif in_ros_args and token == '--':
            in_ros_args = False
        elif in_ros_args and token in _VALUE_FLAGS and index < len(tokens):
            value = tokens[index]
            index += 1
            if token in _PARAM_FLAGS:
                rule = _parameter_rule(value)
                if rule is not None and rule.node and '*' not in rule.node:
                    rules.append(rule)
                    continue
                if rule is not None and not rule.node:
                    global_rules.append(rule)
            elif token in _REMAP_FLAGS:
                head, separator, target = value.partition(':=')
                prefix, _, key = head.rpartition(':')
                if separator and key in ('__ns', '__node', '__name'):
                    remaps.append((prefix, '__ns' if key == '__ns' else '__node', target))
            rcl_args += [token, value]
            continue
        rcl_args.append(token)
    return RosArguments(rcl_args, rules, global_rules, remaps)


def node_fqn(node_name: str, namespace: str,
             remaps: Sequence[tuple[str, str, str]]) -> tuple[str, str]:
    """
    The name and fully qualified name a node will get, by rcl's remapping rules.

    As rcl_node_init: the name is remapped first (``[node:]__node:=``), then the namespace
    (``[node:]__ns:=``) with prefixes matched against the remapped name; ``remaps`` holds the
    node's own arguments' rules before the process's, and the first matching rule wins.
    """
    name = next((value for prefix, key, value in remaps
                 if key == '__node' and prefix in ('', node_name)), node_name)
    namespace = next((value for prefix, key, value in remaps
                      if key == '__ns' and prefix in ('', name)), namespace or '/')
    namespace = '/' + namespace.strip('/')
    return name, namespace.rstrip('/') + '/' + name


def check_rule_values(rules: Sequence[ParameterRule]) -> None:
    """Refuse, naming the rule as typed, a value rcl cannot read (without a node or context)."""
    for rule in rules:
        try:
            remove_ros_args(['-', '--ros-args', '-p', f'{rule.name}:={rule.value}'])
        except Exception as err:
            raise NodeConfigError(rcl_reason(err, rule.text)) from None


def read_rules(rules: Sequence[ParameterRule], context: Any = None) -> list[Parameter]:
    """
    The typed values of ``rules``, read by rcl exactly as it reads any ``-p`` value.

    A short-lived node that hears nothing else reads them under neutral names (so that none
    can touch its own use_sim_time); its error for a value rcl cannot parse is rclpy's
    RCLInvalidROSArgsError. A value rcl cannot read is a NodeConfigError naming the rule.
    """
    if not rules:
        return []
    check_rule_values(rules)
    args = ['--ros-args']
    for index, rule in enumerate(rules):
        args += ['-p', f'value_{index}:={rule.value}']
    reader = Node('softseq_parameter_reader', context=context, cli_args=args,
                  use_global_arguments=False, enable_rosout=False,
                  start_parameter_services=False,
                  automatically_declare_parameters_from_overrides=True)
    try:
        values = [reader.get_parameter(f'value_{index}') for index in range(len(rules))]
    finally:
        reader.destroy_node()
    return [Parameter(rule.name, value.type_, value.value) for rule, value in zip(rules, values)]


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
        """
        Create the node (keywords go to rclpy's Node) and install the validation.

        Node-prefixed ``-p`` rules among its own ``cli_args`` are matched as on the command line
        (:func:`split_ros_arguments`); one meant for another node is refused.
        """
        local = split_ros_arguments(node_kwargs.get('cli_args') or [])
        self.parameter_rules: list[ParameterRule] = []
        if local.rules:
            name, fqn = node_fqn(node_name, node_kwargs.get('namespace') or '', local.remaps)
            self.parameter_rules = local.rules_for(name, fqn)
            for rule in local.rules:
                if rule not in self.parameter_rules:
                    raise NodeConfigError(f'-p {rule.text}: this node is {fqn}, not '
                                          f'{rule.node}')
            node_kwargs['cli_args'] = local.rcl_args
            read = read_rules(self.parameter_rules, node_kwargs.get('context'))
            node_kwargs['parameter_overrides'] = read + list(
                node_kwargs.get('parameter_overrides') or [])
        # What the node was given, to word a refusal of rclpy's in ours.
        self._parameter_overrides_given = list(node_kwargs.get('parameter_overrides') or [])
        try:
            super().__init__(node_name, **node_kwargs)
        except InvalidParameterTypeException as err:
            # rclpy declares use_sim_time itself, before any callback of ours could check it.
            raise NodeConfigError(use_sim_time_reason(str(err))) from None
        fqn_now = self.get_fully_qualified_name()
        if local.rules and local.rules_for(self.get_name(), fqn_now) != self.parameter_rules:
            # The process's own remapping moved the node after the rules were matched.
            raise NodeConfigError(f'-p {local.rules[0].text}: the node is {fqn_now}, not {fqn}')
        self._rules: dict[str, _Rule] = {}
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._post_set)
        # Declarations run the callbacks too; changes apply only once the node is built.
        self.configured = False
        # Set by a node once all its parameters are declared (values can be checked together).
        self.declarations_done = False

    def _declare(self, name: str, default: Any, descriptor: ParameterDescriptor,
                 rule: _Rule) -> Any:
        self._rules[name] = rule
        descriptor.name = name
        return self.declare_checked(name, default, descriptor)

    def declare_checked(self, name: str, default: Any, descriptor: ParameterDescriptor) -> Any:
        """
        ``declare_parameter``'s value; a value refused is one line naming node and parameter.

        ParameterValueError: ``/rig_b/camera: parameter rate_hz: must be > 0, got 0``.
        """
        try:
            return self.declare_parameter(name, default, descriptor).value
        except InvalidParameterTypeException:
            # A parameter rclpy types itself (a read-only text) given another type.
            given = next((p for p in self._parameter_overrides_given if p.name == name), None)
            reason = type_reason(name, Parameter.Type(descriptor.type), given) \
                if given is not None else f'{name}: of the wrong type'
            raise ParameterValueError(f'{self.get_fully_qualified_name()}: parameter {reason}') \
                from None
        except InvalidParameterValueException as err:
            # rclpy wraps the reason in its own words ("Invalid parameter value (0) for
            # parameter. Reason: ...: rate_hz"); ours names the node, which in a rig of three
            # matters, and the parameter once.
            said = re.search(r'Reason: (.*): ' + re.escape(name) + r'$', str(err), re.S)
            reason = self._our_words(name, said[1] if said else str(err))
            raise ParameterValueError(f'{self.get_fully_qualified_name()}: parameter {reason}') \
                from None

    def _our_words(self, name: str, reason: str) -> str:
        """A refusal's reason as ours words it (``name: must be ..., got ...``)."""
        if reason.startswith(f'{name}: '):
            return reason
        # rclpy checks a descriptor's range before our callback sees the value.
        out = re.fullmatch(r'Parameter \S+ out of range\.? Min: \S+, Max: \S+, value: (\S+)',
                           reason)
        rule = self._rules.get(name)
        if out is not None and rule is not None:
            ours = None
            for number in (int, float):
                try:
                    ours = rule.reason(Parameter(name, value=number(out[1])))
                    break
                except ValueError:
                    continue
            if ours is not None:
                return f'{name}: {ours}'
        return f'{name}: {reason}'

    # ---------------------------------------------------------------- set at run time

    def set_parameters(self, parameter_list: list[Parameter]) -> list[SetParametersResult]:
        """As rclpy's, with our one-line reason where rclpy refuses in its own words."""
        results = super().set_parameters(parameter_list)
        return [self._reworded(parameter, result)
                for parameter, result in zip(parameter_list, results)]

    def set_parameters_atomically(self, parameter_list: list[Parameter]) -> SetParametersResult:
        """As rclpy's (the parameter services call it), with our one-line reason."""
        result = super().set_parameters_atomically(parameter_list)
        if result.successful or len(parameter_list) != 1:
            return result
        return self._reworded(parameter_list[0], result)

    def _reworded(self, parameter: Parameter, result: SetParametersResult) -> SetParametersResult:
        """A refusal rclpy words itself (a parameter it types, a read-only one) in our words."""
        if result.successful or not self.has_parameter(parameter.name):
            return result
        name = parameter.name
        if result.reason.startswith('Wrong parameter type'):
            expected = Parameter.Type(self.describe_parameter(name).type)
            reason = type_reason(name, expected, parameter)
        elif result.reason.startswith('Trying to set a read-only parameter'):
            reason = (f'{name}: read-only, it is set when the node starts '
                      f'(--ros-args -p {name}:=...)')
        else:
            reason = self._our_words(name, result.reason)
        return SetParametersResult(successful=False, reason=reason)

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
        return load_rig_scene(name)

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            rule = self._rules.get(parameter.name)
            if rule is None:
                continue
            reason = rule.reason(parameter)
            if reason is not None:
                return SetParametersResult(successful=False,
                                           reason=f'{parameter.name}: {reason}')
        if self.configured or self.declarations_done:
            reason = self._validate_together(parameters)
            if reason is not None:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _validate_together(self, parameters: list[Parameter]) -> str | None:
        """Why values each fine alone cannot run with the node's others; nodes override it."""
        return None

    def _post_set(self, parameters: list[Parameter]) -> None:
        if self.configured:
            self._parameters_changed(parameters)

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        """Apply accepted changes; nodes override this for their dynamic parameters."""


def rcl_reason(err: Exception, rule_text: str | None = None) -> str:
    """
    The reason rcl gives for refusing an argument, in one line (``rule_text``: the rule as typed).

    rclpy's RCLError is not part of its public API: it is known by its name here, and any
    other exception is raised again. rcl reads ``-p`` values as YAML, so a string holding YAML
    (the pump's legs) needs its own quotes: the reason says so when the value refused is a YAML
    list or mapping.
    """
    if type(err).__name__ not in ('RCLError', 'RCLInvalidROSArgsError'):
        raise err
    text = ' '.join(str(err).split(', at ')[0].split())
    rule = re.search(r"rule: '(?:-p|--param) ([^']*)'", text)
    if rule is None:
        return text
    reason = text.split('Error: ', 1)[-1]
    rule_text = rule_text or rule[1]
    value = rule_text.partition(':=')[2].lstrip()
    hint = ('; quote a value that is YAML text, e.g. -p "legs:=\'[{inflate_to_m3: 5.0e-6}]\'"'
            if value[:1] in ('[', '{') else '')
    return f'-p {rule_text}: rcl cannot read the value ({reason}){hint}'


_TYPE_WORDS = {Parameter.Type.BOOL: 'true or false', Parameter.Type.INTEGER: 'an integer',
               Parameter.Type.DOUBLE: 'a number', Parameter.Type.STRING: 'a string'}


def type_reason(name: str, expected: Parameter.Type, given: Parameter) -> str:
    """Our one line for a value of the wrong type given to a parameter rclpy types itself."""
    words = _TYPE_WORDS.get(expected, expected.name.lower().replace('_', ' '))
    return f'{name}: must be {words}, got {given.type_.name.lower()} {given.value!r}'


def use_sim_time_reason(message: str) -> str:
    """Our one line for a ``use_sim_time`` that is no boolean, from rclpy's type error."""
    # rclpy words it "Trying to set parameter 'use_sim_time' to 'maybe' of type 'STRING', ...".
    got = re.search(r"to '(.*)' of type '(\w+)'", message)
    detail = f', got {got[2].lower()} {got[1]!r}' if got else ''
    return f'use_sim_time: must be true or false{detail}'


def _bounds_text(minimum: float | None, maximum: float | None, open_minimum: bool) -> str:
    parts = []
    if minimum is not None:
        parts.append(f'{">" if open_minimum else ">="} {minimum:g}')
    if maximum is not None:
        parts.append(f'<= {maximum:g}')
    return ' and '.join(parts) if parts else 'any value'
