"""
How the package's modules may import each other: no cycles, no private names, one model seam.

Every import counts, also those inside a function (a function-level import that hides a cycle
is still a cycle). The layers themselves (physics free of ROS and of the layers after it, rig
cores free of their drivers) are checked in ``test_package.py``.
"""

import ast
from pathlib import Path
import textwrap

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'softseq_ros'
# The one rig module that may know the quasi-static solver: the actuator's model seam.
MODEL_SEAM = f'{PACKAGE}.rig.model'


def module_name(path: Path, root: Path = REPO) -> str:
    parts = list(path.relative_to(root).with_suffix('').parts)
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def package_modules(root: Path = REPO) -> dict[str, Path]:
    return {module_name(path, root): path for path in sorted((root / PACKAGE).rglob('*.py'))}


def imports_of(source: str, name: str, is_package: bool,
               modules: set[str]) -> tuple[set[str], list[str]]:
    """The package's modules that ``source`` imports, and the private names it imports."""
    package = name.split('.') if is_package else name.split('.')[:-1]
    found: set[str] = set()
    private: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
            private += [alias.name for alias in node.names
                        if any(part.startswith('_') for part in alias.name.split('.'))]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                parent = package[:len(package) - node.level + 1]
                base = '.'.join(parent + ([node.module] if node.module else []))
            if base.split('.')[0] != PACKAGE:
                continue
            for alias in node.names:
                full = f'{base}.{alias.name}'
                if full in modules:
                    found.add(full)
                    continue
                found.add(base)
                if alias.name.startswith('_'):
                    private.append(full)
    return {module for module in found if module in modules and module != name}, private


def import_graph(root: Path = REPO) -> tuple[dict[str, set[str]], dict[str, list[str]]]:
    modules = package_modules(root)
    graph, private = {}, {}
    for name, path in modules.items():
        graph[name], names = imports_of(path.read_text(encoding='utf-8'), name,
                                        path.name == '__init__.py', set(modules))
        if names:
            private[name] = names
    return graph, private


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    found.append(sorted(group))
    return found


def test_the_checks_catch_a_hidden_cycle_and_a_private_import(tmp_path):
    # A cycle hidden behind a function-level import, and a private name taken from a module.
    sources = {
        'a.py': 'from softseq_ros.b import helper\n',
        'b.py': 'def helper():\n    from softseq_ros.a import thing\n',
        'c.py': 'from softseq_ros.a import _Context\nfrom softseq_ros.b import helper\n',
        '__init__.py': '',
    }
    for file, text in sources.items():
        (tmp_path / PACKAGE).mkdir(exist_ok=True)
        (tmp_path / PACKAGE / file).write_text(textwrap.dedent(text))
    graph, private = import_graph(tmp_path)
    assert cycles(graph) == [[f'{PACKAGE}.a', f'{PACKAGE}.b']]
    assert private == {f'{PACKAGE}.c': [f'{PACKAGE}.a._Context']}


def test_no_module_of_the_package_imports_in_a_cycle():
    graph, _ = import_graph()
    assert len(graph) > 50
    assert cycles(graph) == []


def test_no_module_imports_a_private_name_of_another():
    # A name with a leading underscore is its module's business; what others need is public.
    _, private = import_graph()
    assert private == {}


def test_benchmarks_tests_and_tools_use_only_public_names():
    modules = set(package_modules())
    offenders = {}
    for folder in ('bench', 'test', 'tools'):
        for path in sorted((REPO / folder).rglob('*.py')):
            _, private = imports_of(path.read_text(encoding='utf-8'), f'{folder}.{path.stem}',
                                    False, modules)
            if private:
                offenders[str(path.relative_to(REPO))] = private
    assert offenders == {}


PHYSICS_MODELS = (f'{PACKAGE}.quasistatic', f'{PACKAGE}.dynamic')


def test_only_the_model_seam_of_the_rig_knows_the_physics_models():
    graph, _ = import_graph()
    rig = {name for name in graph if name.startswith(f'{PACKAGE}.rig.')}
    assert MODEL_SEAM in rig
    knowing = sorted(name for name in rig
                     if any(module.startswith(PHYSICS_MODELS) for module in graph[name]))
    assert knowing == [MODEL_SEAM]
    # The nodes and the batch runner reach the physics through the rig's cores and model too.
    drivers = {name for name in graph if name.startswith((f'{PACKAGE}.nodes', f'{PACKAGE}.batch'))}
    assert not {name: sorted(m for m in graph[name] if m.startswith(PHYSICS_MODELS))
                for name in drivers if any(m.startswith(PHYSICS_MODELS) for m in graph[name])}


# Data flows one way: scene -> segment models -> physics -> rig cores -> node or batch ->
# wire -> bag -> analysis. A layer never imports the layers it feeds.
NEVER_IMPORTS = {
    'wire': ('rig', 'nodes', 'batch', 'bag', 'analysis', 'cli', 'fem', 'quasistatic', 'dynamic',
             'testing', 'parallel'),
    'bag': ('rig', 'nodes', 'batch', 'analysis', 'cli', 'fem', 'quasistatic', 'dynamic',
            'testing'),
    'analysis': ('rig', 'nodes', 'batch', 'cli', 'testing'),
}


def layer_faults(graph: dict[str, set[str]]) -> dict[str, list[str]]:
    """Each module that imports a layer its own layer must never import, with those imports."""
    faults = {}
    for name, imported in graph.items():
        layer = name.split('.')[1] if name.count('.') else ''
        banned = tuple(f'{PACKAGE}.{other}' for other in NEVER_IMPORTS.get(layer, ()))
        wrong = sorted(module for module in imported
                       if any(module == b or module.startswith(b + '.') for b in banned))
        if wrong:
            faults[name] = wrong
    return faults


def test_the_layer_check_catches_a_bag_module_importing_the_rig():
    graph = {f'{PACKAGE}.bag.info': {f'{PACKAGE}.rig.build', f'{PACKAGE}.wire.contract'},
             f'{PACKAGE}.wire.payloads': {f'{PACKAGE}.bag.writer'},
             f'{PACKAGE}.rig.pump': {f'{PACKAGE}.wire.values'}}
    assert layer_faults(graph) == {f'{PACKAGE}.bag.info': [f'{PACKAGE}.rig.build'],
                                   f'{PACKAGE}.wire.payloads': [f'{PACKAGE}.bag.writer']}


def test_data_flows_one_way_through_the_wire_the_bag_and_the_analysis():
    graph, _ = import_graph()
    assert {name for name in graph if name.startswith(f'{PACKAGE}.wire.')}
    assert layer_faults(graph) == {}


# What the public API's functions give back tells their job: a run of the rig into a bag, or a
# bag read back. Each job has one public function.
BATCH_RESULTS = ('BatchResult',)
BAG_READS = ('Recording', 'BagArrays', 'BagMessage', 'BagInfo', 'BagSummary')


def public_api() -> dict[str, object]:
    """Every name the package's faces export: the top level's and each subpackage's __all__."""
    import importlib

    found = {}
    faces = [PACKAGE] + sorted(name for name, path in package_modules().items()
                               if path.name == '__init__.py' and name != PACKAGE)
    for face in faces:
        module = importlib.import_module(face)
        for name in getattr(module, '__all__', ()):
            found[f'{face}.{name}'] = getattr(module, name)
    return found


def jobs_of(api: dict[str, object]) -> dict[str, list[str]]:
    """The public names that run a batch and those that read a bag, by their return types."""
    import inspect

    jobs: dict[str, list[str]] = {'run a batch': [], 'read a bag': []}
    for name, value in api.items():
        if inspect.isclass(value):
            returned = value.__name__
        elif callable(value):
            annotation = inspect.signature(value).return_annotation
            returned = annotation if isinstance(annotation, str) else getattr(
                annotation, '__name__', str(annotation))
        else:
            continue
        words = set(returned.replace('[', ' ').replace(']', ' ').replace('|', ' ').split())
        if words & set(BATCH_RESULTS):
            jobs['run a batch'].append(name)
        if words & set(BAG_READS):
            jobs['read a bag'].append(name)
    return jobs


def test_the_job_check_catches_a_second_public_bag_reader():
    class Recording:
        pass

    class BatchResult:
        pass

    def load(directory: str) -> Recording:
        """One way."""

    def read(directory: str) -> 'Iterator[BagMessage]':  # noqa: F821 - read as text only
        """Another."""

    def run(scene: str) -> BatchResult:
        """A batch."""

    assert jobs_of({'a.load': load, 'b.read': read, 'c.run': run, 'c.n': 3}) == {
        'run a batch': ['c.run'], 'read a bag': ['a.load', 'b.read']}


def test_one_public_way_to_run_a_batch_and_one_to_read_a_bag():
    api = public_api()
    assert f'{PACKAGE}.solve' in api and f'{PACKAGE}.bag.BagWriter' in api
    assert jobs_of(api) == {'run a batch': [f'{PACKAGE}.run'],
                            'read a bag': [f'{PACKAGE}.load_recording']}


# The redistribution flow of a snap (its equations, its rest and stability tests, its
# integration) lives in the landing's module alone: the other modules of the quasi-static
# solver hand it their folds and get landings back.
LANDING = f'{PACKAGE}.quasistatic.landing'
FLOW_OBJECTS = ('RedistributionFlow', 'FlowLandings', 'stable')
INTEGRATORS = ('solve_ivp', 'odeint', 'ode', 'Radau', 'LSODA', 'BDF', 'RK45')


def _is_mean(node: ast.AST) -> bool:
    """A call of ``mean`` or ``average`` (np.mean(p), p.mean(), mean(p, axis=1))."""
    if not isinstance(node, ast.Call):
        return False
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, 'id', '')
    return name in ('mean', 'average')


def flow_reaches(source: str, name: str) -> list[str]:
    """
    Where ``source`` (module ``name``) reaches into the landing's flow: imports its flow
    object or stability test, imports an ODE integrator, or writes a flow's forcing (a
    pressure less the mean pressure, or the mean less a pressure).
    """
    package = name.split('.')[:-1]
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                base = '.'.join(package[:len(package) - node.level + 1]
                                + ([node.module] if node.module else []))
            for alias in node.names:
                if base == LANDING and alias.name in FLOW_OBJECTS:
                    found.append(f'imports {alias.name} from the landing')
                if base.startswith('scipy.integrate') and alias.name in INTEGRATORS:
                    found.append(f'imports the integrator {alias.name}')
        elif isinstance(node, ast.Attribute) and node.attr in FLOW_OBJECTS[:2]:
            found.append(f'uses {node.attr}')
        elif (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Sub)
              and (_is_mean(node.left) or _is_mean(node.right))):
            found.append(f'writes a flow forcing in line {node.lineno}')
    return found


def test_the_flow_check_catches_a_module_reaching_into_the_flow():
    sources = {
        'ends': 'from softseq_ros.quasistatic.landing import RedistributionFlow\n',
        'relative': 'from .landing import stable, SnapLandings\n',
        'drift': 'import numpy as np\ndef drift(p, n):\n    return -np.dot(p - p.mean(), n)\n',
        'batched': 'import numpy as np\nf = np.mean(p, axis=1, keepdims=True) - p\n',
        'alone': 'from scipy.integrate import solve_ivp\n',
        'module': 'from softseq_ros.quasistatic import landing\nx = landing.FlowLandings\n',
        'clean': 'from softseq_ros.quasistatic.landing import SnapLandings\nd = p - q\n',
    }
    found = {key: flow_reaches(text, f'{PACKAGE}.quasistatic.{key}')
             for key, text in sources.items()}
    assert found == {
        'ends': ['imports RedistributionFlow from the landing'],
        'relative': ['imports stable from the landing'],
        'drift': ['writes a flow forcing in line 3'],
        'batched': ['writes a flow forcing in line 2'],
        'alone': ['imports the integrator solve_ivp'],
        'module': ['uses FlowLandings'],
        'clean': [],
    }


def test_only_the_landing_writes_the_redistribution_flow():
    modules = package_modules()
    quasistatic = {name: path for name, path in modules.items()
                   if name.startswith(f'{PACKAGE}.quasistatic.')}
    assert LANDING in quasistatic and len(quasistatic) > 5
    # The check sees the landing's own flow.
    assert flow_reaches(quasistatic[LANDING].read_text(encoding='utf-8'), LANDING)
    offenders = {name: flow_reaches(path.read_text(encoding='utf-8'), name)
                 for name, path in quasistatic.items() if name != LANDING}
    assert {name: found for name, found in offenders.items() if found} == {}
