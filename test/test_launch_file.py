"""
launch/rig.launch.py, read as source (launch itself is not installable here): every node it
starts is one of our executables, every parameter it gives is one that node declares, every
launch argument it uses is declared, and setup.py installs it where ros2 launch looks.
"""

import ast
from functools import lru_cache
import importlib
import inspect
from pathlib import Path

from rclpy.node import Node
from test_package import read_setup_py

from softseq_ros.nodes.runner import declared_parameters

REPO = Path(__file__).resolve().parents[1]
LAUNCH = REPO / 'launch' / 'rig.launch.py'


def _keyword(call: ast.Call, name: str) -> ast.AST | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [node for node in ast.walk(tree) if isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name) and node.func.id == name]


def launched_nodes(path: Path = LAUNCH) -> list[dict]:
    """Each launch_ros Node(...) of the file: package, executable, name, parameter names."""
    tree = ast.parse(path.read_text(encoding='utf-8'))
    found = []
    for call in _calls(tree, 'Node'):
        parameters = _keyword(call, 'parameters')
        names: list[str] = []
        if parameters is not None:
            assert isinstance(parameters, ast.List), 'parameters must be a list of dicts'
            for item in parameters.elts:
                assert isinstance(item, ast.Dict), 'parameters must be dicts, not files'
                names += [ast.literal_eval(key) for key in item.keys]
        found.append({field: ast.literal_eval(_keyword(call, field))
                      for field in ('package', 'executable', 'name')} | {'parameters': names})
    return found


@lru_cache(maxsize=None)
def declared_names(cls: type) -> frozenset[str]:
    """The parameters ``cls`` declares (a dry build of the node: nothing starts)."""
    return frozenset(name for name, _, _ in declared_parameters(cls))


def node_class(target: str) -> type:
    """
    The node class an executable (``module:function``) runs: the module's Node subclass.

    An executable in ``softseq_ros.nodes.entry`` loads its node's module by name
    (``_run('actuator')``): that module is read off the function's body.
    """
    module_name, _, function = target.partition(':')
    module = importlib.import_module(module_name)
    if module_name == 'softseq_ros.nodes.entry':
        body = ast.parse(inspect.getsource(getattr(module, function)))
        loads = [ast.literal_eval(call.args[0]) for call in _calls(body, '_run')]
        assert len(loads) == 1, f'{target}: expected one _run call, found {loads}'
        module = importlib.import_module(f'softseq_ros.nodes.{loads[0]}')
    classes = [value for value in vars(module).values()
               if isinstance(value, type) and issubclass(value, Node)
               and value.__module__ == module.__name__ and hasattr(value, 'NODE_NAME')]
    assert len(classes) == 1, f'{module.__name__}: expected one node class, found {classes}'
    return classes[0]


def test_the_launch_file_starts_our_executables_with_parameters_they_declare():
    scripts = read_setup_py()['console_scripts']
    nodes = launched_nodes()
    assert {n['executable'] for n in nodes} == {'syringe_pump', 'actuator', 'camera',
                                                 'recorder'}
    for node in nodes:
        assert node['package'] == 'softseq_ros'
        assert node['executable'] in scripts, f"{node['executable']} is no console script"
        cls = node_class(scripts[node['executable']])
        assert node['name'] == cls.NODE_NAME
        declared = declared_names(cls)
        undeclared = set(node['parameters']) - declared
        assert not undeclared, f"{node['executable']} declares no {sorted(undeclared)}"
        assert node['parameters'], f"{node['executable']} is given no parameter"


def test_every_launch_argument_used_is_declared_with_a_default_and_description():
    tree = ast.parse(LAUNCH.read_text(encoding='utf-8'))
    declared = {}
    for call in _calls(tree, 'DeclareLaunchArgument'):
        declared[ast.literal_eval(call.args[0])] = call
        assert _keyword(call, 'default_value') is not None
        assert ast.literal_eval(_keyword(call, 'description'))
    used = {ast.literal_eval(call.args[0]) for call in _calls(tree, 'LaunchConfiguration')}
    assert used == set(declared) >= {'namespace', 'scene'}
    # Every node runs in the namespace argument.
    for call in _calls(tree, 'Node'):
        namespace = _keyword(call, 'namespace')
        assert isinstance(namespace, ast.Name) and namespace.id == 'namespace'


def test_the_checks_catch_a_parameter_no_node_declares(tmp_path):
    bad = tmp_path / 'bad.launch.py'
    bad.write_text(LAUNCH.read_text(encoding='utf-8').replace(
        "parameters=[{'scene': scene}]),", "parameters=[{'scene': scene, 'rate': 5}]),", 1))
    node = next(n for n in launched_nodes(bad) if 'rate' in n['parameters'])
    cls = node_class(read_setup_py()['console_scripts'][node['executable']])
    assert 'rate' not in declared_names(cls) and 'scene' in declared_names(cls)

