"""
The adversarial suite (bench/bench_adversarial.py) reaches every entry of the registries.

Its option cases are read from softseq's own parser, so a command or option is tried the day
it lands; its scene cases change every key of their base scenes, and those bases must hold
every key of the scene reference (softseq_ros/scene/reference.py). A new command, option or
scene key without cases fails here.
"""

from pathlib import Path
import sys

import pytest

from softseq_ros.scene import reference
from softseq_ros.scene.loader import scene_from_dict

BENCH = Path(__file__).resolve().parent.parent / 'bench'
sys.path.insert(0, str(BENCH))

import bench_adversarial as adversarial  # noqa: E402

# Keys of the reference no base scene holds, and where they are tried instead.
COVERED_ELSEWHERE = {
    'segments[].design': 'the design class changes every key of a design file; a scene naming '
                         'a design needs its FEM table, which the suite does not compute',
}


def test_every_command_and_every_option_with_a_value_has_cases():
    names = {case.name for case in adversarial.option_cases()}
    commands = adversarial.parser_commands()
    assert {words[0] for words, _ in commands} >= {'solve', 'run', 'report', 'fit', 'ros'}
    for words, parser in commands:
        for option in adversarial.valued_options(parser):
            for label, _ in adversarial.BAD_OPTION_VALUES:
                assert f'{" ".join(words)} {option} {label}' in names


def test_the_scene_bases_hold_every_key_of_the_scene_reference():
    held = set().union(*(adversarial.scene_key_paths(adversarial._scene_document(base))
                         for base in adversarial.SCENE_BASES))
    documented = {f'{section.path}.{key.name}' if section.path else key.name
                  for section in reference.SCENE_SECTIONS for key in section.keys}
    missing = documented - held - set(COVERED_ELSEWHERE)
    assert not missing, f'no base scene of the adversarial suite holds {sorted(missing)}'
    # And every case of a base is a case of the suite.
    names = {case.name for case in adversarial.scene_cases()}
    assert any(name.startswith('every_block: supply.trapped_gas_m3') for name in names)


@pytest.mark.parametrize('base', adversarial.MAXIMAL_SCENE_BASES)
def test_each_written_base_scene_loads_as_it_is(base, tmp_path):
    import softseq_ros
    from softseq_ros.quasistatic.solve import segments_graph

    # A base that did not load would make every change of it a refusal for another reason.
    adversarial.write_companions(tmp_path, base)
    scene = scene_from_dict(adversarial._scene_document(base), tmp_path / 'scene.yaml',
                            segments_graph)
    if scene.regulator is not None:
        # Behind a regulator the job tried is solve: its flips, each segment a hysteron.
        assert softseq_ros.solve(scene).flips
        return
    assert softseq_ros.classify(scene) in ('none', 'partial', 'symmetric', 'asymmetric')


def test_every_node_and_every_lifecycle_transition_from_every_state_has_service_cases():
    names = {case.name for case in adversarial.service_cases()}
    for node in adversarial._node_classes():
        if node == 'syringe_pump':
            for state in adversarial.PUMP_STATES:
                assert f'syringe_pump in state {state}: every service, every request' in names
                for managed in ('inactive', 'active'):
                    assert (f'managed_syringe_pump {managed}, pump {state}: every service, '
                            'every request') in names
        else:
            assert f'{node}: every service, every request' in names
    for state, _ in adversarial.LIFECYCLE_PATH:
        for transition in adversarial.LIFECYCLE_IDS:
            assert f'managed_syringe_pump in state {state}: transition {transition}' in names
    # Every lifecycle id a state has is among those tried, and every state is reached.
    assert set(adversarial.LIFECYCLE_ALLOWED) == {s for s, _ in adversarial.LIFECYCLE_PATH}
    for allowed in adversarial.LIFECYCLE_ALLOWED.values():
        assert allowed <= set(adversarial.LIFECYCLE_IDS)


def test_every_file_a_command_reads_has_the_file_battery():
    # Found from the parser (Path-typed arguments, or arguments whose help names a file or a
    # folder): each is in FILE_INPUTS, with its cases, or in NOT_FILE_INPUTS saying why not.
    names = {case.name for case in adversarial.file_cases()}
    found = set()
    for words, parser in adversarial.parser_commands():
        for argument in adversarial.file_arguments(parser):
            key = (' '.join(words), argument)
            found.add(key)
            assert key in adversarial.FILE_INPUTS or key in adversarial.NOT_FILE_INPUTS, (
                f'softseq {key[0]} {key[1]} names a file: give it the file battery '
                '(bench_adversarial.FILE_INPUTS) or say in NOT_FILE_INPUTS why it reads none')
            if key not in adversarial.FILE_INPUTS:
                continue
            wanted = adversarial.file_case_names(words, argument)
            assert set(wanted) <= names
            for label in ('a FIFO nobody writes', 'unreadable (mode 000)', 'empty',
                          'one huge line', 'SIGINT while it waits on a FIFO',
                          'SIGTERM while it waits on a FIFO'):
                assert any(name.endswith(f': {label}') for name in wanted), (key, label)
    # No entry for an argument the parser no longer has.
    stale = (set(adversarial.FILE_INPUTS) | set(adversarial.NOT_FILE_INPUTS)) - found
    assert not stale, f'FILE_INPUTS or NOT_FILE_INPUTS name arguments no command has: {stale}'
    # The kinds of input every command reads are all there.
    kinds = {kind for kind, _ in adversarial.FILE_INPUTS.values()}
    assert kinds == {'scene', 'yaml', 'csv', 'bag'}
    assert any(name.endswith('(metadata.yaml): nested 100000 deep') for name in names)
    assert any(name.endswith('(the .mcap): a folder') for name in names)
