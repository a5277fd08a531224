"""The repository is a correct ament_python package, lints clean and keeps physics free of ROS.

What is checked here is what a ROS user relies on without seeing it: colcon recognising the
package as ament_python (a broken package.xml makes it fall back to plain Python silently),
``ros2 run`` finding the executables through the ament index, and the physics layer importing
without rclpy so that it works in a notebook.
"""

import ast
import os
from pathlib import Path
import re
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET

from ament_index_python.packages import get_package_prefix
from catkin_pkg.package import parse_package_string
import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = 'softseq_ros'
VENV_BIN = Path(sys.prefix) / 'bin'
# The executables the README promises to ROS users.
DOCUMENTED_EXECUTABLES = {'softseq', 'syringe_pump', 'actuator', 'camera', 'recorder',
                          'sim_clock', 'rig', 'managed_syringe_pump', 'pressure_hold'}
# Top-level modules that exist only with a ROS install (or the ROS wheels).
ROS_MODULES = {
    'rclpy', 'rcl_interfaces', 'rosidl_runtime_py', 'ament_index_python', 'builtin_interfaces',
    'std_msgs', 'std_srvs', 'geometry_msgs', 'sensor_msgs', 'visualization_msgs', 'nav_msgs',
    'rosgraph_msgs', 'launch', 'launch_ros', 'diagnostic_msgs', 'lifecycle_msgs',
}
# Data flows scene -> segment models -> quasi-static solver -> rig core -> node or batch ->
# topic -> bag -> analysis: the physics imports none of the later layers, and the rig's cores
# none of their drivers.
PHYSICS_LAYERS = ('segments', 'scene', 'quasistatic', 'dynamic')
DOWNSTREAM_LAYERS = {f'{PACKAGE}.{layer}' for layer in (
    'rig', 'nodes', 'batch', 'bag', 'analysis', 'cli', 'fem')}
# Within the physics: segment models never read a user's file and know no solver; the user's
# inputs know no solver.
PHYSICS_DOWNSTREAM = {
    'segments': DOWNSTREAM_LAYERS | {f'{PACKAGE}.scene', f'{PACKAGE}.quasistatic',
                                     f'{PACKAGE}.dynamic'},
    'scene': DOWNSTREAM_LAYERS | {f'{PACKAGE}.quasistatic', f'{PACKAGE}.dynamic'},
    # The two physics models are alternatives: neither knows the other.
    'quasistatic': DOWNSTREAM_LAYERS | {f'{PACKAGE}.dynamic'},
    'dynamic': DOWNSTREAM_LAYERS | {f'{PACKAGE}.quasistatic'},
}
RIG_DRIVERS = {f'{PACKAGE}.{layer}' for layer in ('nodes', 'batch', 'analysis', 'cli', 'fem')}


# ---------------------------------------------------------------------------------------------
# setup.py, read statically (running it would need setuptools' command machinery)

def _static_value(node: ast.AST, names: dict):
    """Evaluate literals, module-level constant names and string concatenation."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name) and node.id in names:
        return names[node.id]
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _static_value(node.left, names) + _static_value(node.right, names)
    if isinstance(node, (ast.List, ast.Tuple)):
        return [_static_value(item, names) for item in node.elts]
    if isinstance(node, ast.Dict):
        return {_static_value(k, names): _static_value(v, names)
                for k, v in zip(node.keys, node.values, strict=True)}
    raise ValueError(f'setup.py: cannot read {ast.unparse(node)!r} without running it')


def read_setup_py(path: Path = REPO / 'setup.py') -> dict:
    """Return name, version and console_scripts {executable: target} from setup.py."""
    tree = ast.parse(path.read_text(), filename=str(path))
    names = {}
    for statement in tree.body:
        if (isinstance(statement, ast.Assign) and len(statement.targets) == 1
                and isinstance(statement.targets[0], ast.Name)):
            try:
                names[statement.targets[0].id] = _static_value(statement.value, names)
            except ValueError:
                pass
    calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call)
             and getattr(node.func, 'id', getattr(node.func, 'attr', None)) == 'setup']
    assert len(calls) == 1, f'{path}: expected one setup() call, found {len(calls)}'
    keywords = {kw.arg: kw.value for kw in calls[0].keywords}
    scripts = {}
    for line in _static_value(keywords['entry_points'], names)['console_scripts']:
        executable, _, target = (part.strip() for part in line.partition('='))
        assert executable not in scripts, f'{path}: console script {executable} twice'
        scripts[executable] = target
    return {
        'name': _static_value(keywords['name'], names),
        'version': _static_value(keywords['version'], names),
        'console_scripts': scripts,
    }


def test_setup_py_declares_the_documented_executables():
    scripts = read_setup_py()['console_scripts']
    assert DOCUMENTED_EXECUTABLES <= set(scripts), (
        f'setup.py console_scripts lack {sorted(DOCUMENTED_EXECUTABLES - set(scripts))}')
    for executable, target in scripts.items():
        module, _, function = target.partition(':')
        assert module.startswith(PACKAGE + '.') and function.isidentifier(), (
            f'setup.py: console script {executable} = {target!r} is not "{PACKAGE}.module:func"')


def test_static_setup_reader_resolves_names_and_concatenation(tmp_path):
    # Guards the reader itself: the package tests below are only as good as what it returns.
    setup_py = tmp_path / 'setup.py'
    setup_py.write_text(textwrap.dedent("""
        from setuptools import setup
        NAME = 'demo_pkg'
        setup(name=NAME, version='1.2' + '.3',
              entry_points={'console_scripts': ['run_me = ' + NAME + '.cli:main']})
    """))
    assert read_setup_py(setup_py) == {
        'name': 'demo_pkg', 'version': '1.2.3', 'console_scripts': {'run_me': 'demo_pkg.cli:main'}}


# ---------------------------------------------------------------------------------------------
# package.xml

def test_package_xml_is_format_3_ament_python_matching_setup_py():
    root = ET.parse(REPO / 'package.xml').getroot()
    setup = read_setup_py()
    assert root.tag == 'package' and root.get('format') == '3', 'package.xml: not format 3'
    assert root.findtext('name') == setup['name'] == PACKAGE
    assert root.findtext('version') == setup['version'], (
        f"package.xml version {root.findtext('version')} != setup.py version {setup['version']}")
    assert [e.text for e in root.findall('export/build_type')] == ['ament_python']
    assert (root.findtext('description') or '').strip(), 'package.xml: empty description'
    assert root.findtext('license'), 'package.xml: no license'
    maintainers = root.findall('maintainer')
    assert maintainers and all(m.get('email') for m in maintainers), (
        'package.xml: every maintainer needs an email attribute')
    exec_depends = {e.text for e in root.findall('exec_depend')}
    assert {'rclpy', 'std_msgs'} <= exec_depends, 'package.xml: nodes need rclpy and std_msgs'


def test_package_xml_passes_the_parser_colcon_uses():
    # colcon-ros reads package.xml with catkin_pkg and, when that fails (a bad e-mail, a
    # misplaced tag), quietly treats the folder as a plain Python package. Fail loudly instead.
    warnings = []
    package = parse_package_string(
        (REPO / 'package.xml').read_text(), filename=str(REPO / 'package.xml'), warnings=warnings)
    assert warnings == []
    assert package.name == PACKAGE and package.package_format == 3


# ---------------------------------------------------------------------------------------------
# colcon build into a temporary workspace

def _run(command: list, cwd: Path, env: dict) -> subprocess.CompletedProcess:
    result = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True,
                            stdin=subprocess.DEVNULL, timeout=600)
    assert result.returncode == 0, (
        f'{" ".join(map(str, command))} failed ({result.returncode}):\n'
        f'{result.stdout[-3000:]}\n{result.stderr[-3000:]}')
    return result


@pytest.fixture(scope='module')
def colcon_workspace(tmp_path_factory) -> dict:
    """Build the repository with colcon, all outputs outside the repository; return the paths."""
    work = tmp_path_factory.mktemp('colcon')
    env = dict(os.environ)
    env['COLCON_HOME'] = str(work / 'colcon_home')  # no user defaults.yaml changes the build
    colcon = str(VENV_BIN / 'colcon')
    outputs_before = {name: (REPO / name).exists() for name in ('build', 'install', 'log')}
    listed = _run([colcon, '--log-base', work / 'log', 'list', '--base-paths', REPO], work, env)
    _run([colcon, '--log-base', work / 'log', 'build', '--base-paths', REPO,
          '--build-base', work / 'build', '--install-base', work / 'install'], work, env)
    outputs_after = {name: (REPO / name).exists() for name in ('build', 'install', 'log')}
    return {'list': listed.stdout, 'install': work / 'install', 'repo_outputs': (
        outputs_before, outputs_after)}


def test_colcon_identifies_an_ament_python_package(colcon_workspace):
    lines = [line.split() for line in colcon_workspace['list'].splitlines()]
    assert [PACKAGE, str(REPO), '(ros.ament_python)'] in lines, colcon_workspace['list']


def test_colcon_build_installs_the_executables_where_ros2_run_looks(colcon_workspace, monkeypatch):
    install = colcon_workspace['install']
    # ros2 run resolves <prefix> through the ament index, then runs <prefix>/lib/<package>/<exe>.
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(install / PACKAGE))
    prefix = Path(get_package_prefix(PACKAGE))
    assert prefix == install / PACKAGE
    lib = prefix / 'lib' / PACKAGE
    for executable in read_setup_py()['console_scripts']:
        path = lib / executable
        assert path.is_file() and os.access(path, os.X_OK), f'{path} missing or not executable'


def test_colcon_build_installs_the_index_marker_and_package_xml(colcon_workspace):
    share = colcon_workspace['install'] / PACKAGE / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()
    installed_xml = share / PACKAGE / 'package.xml'
    assert installed_xml.read_text() == (REPO / 'package.xml').read_text()


def test_colcon_build_installs_the_launch_file(colcon_workspace):
    # Where ros2 launch softseq_ros rig.launch.py finds it (test_launch_file.py reads it).
    installed = colcon_workspace['install'] / PACKAGE / 'share' / PACKAGE / 'launch'
    assert (installed / 'rig.launch.py').read_bytes() == \
        (REPO / 'launch' / 'rig.launch.py').read_bytes()


def test_colcon_build_leaves_no_outputs_in_the_repository(colcon_workspace):
    before, after = colcon_workspace['repo_outputs']
    assert after == before


# ---------------------------------------------------------------------------------------------
# lint

def test_ruff_check_passes_on_the_repository():
    result = subprocess.run([str(VENV_BIN / 'ruff'), 'check', '--no-cache', '.'], cwd=REPO,
                            capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr


# ---------------------------------------------------------------------------------------------
# physics stays free of ROS

def imported_modules(source: str, module_name: str) -> set[str]:
    """Return the absolute names of every module a source file imports, relative ones resolved.

    Also counts importlib.import_module('x') and __import__('x') with a literal name.
    """
    package_parts = module_name.split('.')[:-1]
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                parent = package_parts[:len(package_parts) - node.level + 1]
                base = '.'.join(parent + ([node.module] if node.module else []))
            found.add(base)
            found.update(f'{base}.{alias.name}' for alias in node.names)
        elif (isinstance(node, ast.Call) and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)
              and (getattr(node.func, 'attr', None) == 'import_module'
                   or getattr(node.func, 'id', None) == '__import__')):
            found.add(node.args[0].value)
    return found


def forbidden_imports(modules: set[str], layers: set[str] = DOWNSTREAM_LAYERS) -> set[str]:
    """Return the imports among modules that would pull ROS or one of ``layers`` in."""
    return {name for name in modules if name.split('.')[0] in ROS_MODULES
            or any(name == layer or name.startswith(layer + '.') for layer in layers)}


def test_import_scanner_catches_every_way_of_importing_ros():
    source = textwrap.dedent("""
        import numpy as np
        import rclpy.node
        from std_msgs.msg import Float64
        from ..nodes import actuator
        from .. import bag
        from . import segments
        import importlib
        importlib.import_module('geometry_msgs.msg')
        def late():
            from rclpy.qos import QoSProfile
    """)
    found = forbidden_imports(imported_modules(source, f'{PACKAGE}.quasistatic.example'))
    assert {'rclpy.node', 'std_msgs.msg', f'{PACKAGE}.nodes', f'{PACKAGE}.bag',
            'geometry_msgs.msg', 'rclpy.qos'} <= found
    assert not any(name.startswith(('numpy', f'{PACKAGE}.quasistatic')) for name in found)


def layer_offenders(folder: str, layers: set[str]) -> dict[str, list[str]]:
    """Files under softseq_ros/<folder> that import ROS or one of ``layers``."""
    root = REPO / PACKAGE / folder
    sources = sorted(root.rglob('*.py'))
    assert len(sources) > 1, f'no modules found under {root}'
    offenders = {}
    for path in sources:
        module = '.'.join(path.relative_to(REPO).with_suffix('').parts)
        bad = forbidden_imports(imported_modules(path.read_text(), module), layers)
        if bad:
            offenders[str(path.relative_to(REPO))] = sorted(bad)
    return offenders


@pytest.mark.parametrize('layer', PHYSICS_LAYERS)
def test_physics_sources_import_no_ros_and_no_downstream_layer(layer):
    assert layer_offenders(layer, PHYSICS_DOWNSTREAM[layer]) == {}


def test_rig_cores_import_no_ros_and_none_of_their_drivers():
    # The cores never know what drives them: no rclpy, no node, no batch runner.
    assert layer_offenders('rig', RIG_DRIVERS) == {}


def test_readme_layout_names_every_package_and_module_of_the_top_level():
    readme = (REPO / 'README.md').read_text(encoding='utf-8')
    layout = readme.split('## Layout', 1)[1].split('\n## ', 1)[0]
    root = REPO / PACKAGE
    names = [f'{PACKAGE}/{p.name}/' for p in root.iterdir()
             if p.is_dir() and (p / '__init__.py').is_file()]
    names += [f'{PACKAGE}/{p.name}' for p in root.glob('*.py')]
    missing = [name for name in names if name not in layout]
    assert missing == [], f'README layout does not mention {missing}'
    # And it names nothing that is gone.
    for mentioned in re.findall(rf'{PACKAGE}/[a-z_]+(?:/|\.py)', layout):
        assert (REPO / mentioned).exists(), f'README layout names {mentioned}, which is gone'


def test_physics_imports_without_rclpy_at_run_time(ros_env):
    # Catches what a scan of the physics folders cannot see: softseq_ros/__init__.py or a
    # helper module outside them pulling rclpy in.
    script = textwrap.dedent(f"""
        import importlib, pkgutil, sys
        sys.modules['rclpy'] = None  # any attempt to import rclpy now raises ImportError
        for layer in {PHYSICS_LAYERS!r}:
            package = importlib.import_module('softseq_ros.' + layer)
            for info in pkgutil.walk_packages(package.__path__, package.__name__ + '.'):
                importlib.import_module(info.name)
        ros = set({sorted(ROS_MODULES)!r})
        loaded = sorted(m for m, mod in sys.modules.items() if mod and m.split('.')[0] in ros)
        assert not loaded, f'physics loaded ROS modules: {{loaded}}'
    """)
    result = subprocess.run([sys.executable, '-c', script], cwd=REPO, env=ros_env,
                            capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
