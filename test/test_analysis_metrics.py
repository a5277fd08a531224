"""Numbers that can be quoted: a metric that does not apply says so, with its reason."""

import json
from pathlib import Path

import pytest
import yaml

from softseq_ros.analysis.compare import compare_bags
from softseq_ros.analysis.report import write_report
from softseq_ros.batch import run_scene

CONFIG = Path(__file__).resolve().parents[1] / 'config'
ML = 1e-6


def _bag(folder: Path, source: str, legs: list[dict], triggers: list[float]) -> Path:
    """A batch bag of a shipped scene with a short, fast programme (20 mL/s at 50 Hz)."""
    scene = yaml.safe_load((CONFIG / source).read_text())
    scene['name'] = Path(source).stem + '_short'
    scene['pump'].update({'flow_rate_m3_per_s': 2.0e-5, 'rate_hz': 50, 'legs': legs,
                          'cycles': 1})
    scene['camera'] = {'rate_hz': 5, 'trigger_injected_m3': triggers}
    path = folder / f'{scene["name"]}.yaml'
    path.write_text(yaml.safe_dump(scene))
    bag = folder / scene['name']
    run_scene(path, bag, show_progress=False, start_time_ns=10**18)
    return bag


@pytest.fixture(scope='module')
def linear(tmp_path_factory) -> Path:
    """Fig. 1 'none': two linear segments, 0 -> 65 mL -> 0, no camera trigger volumes."""
    return _bag(tmp_path_factory.mktemp('none'), 'fig1_none.yaml',
                [{'inflate_to_m3': 6.5e-5}, {'deflate_to_m3': 0.0}], [])


@pytest.fixture(scope='module')
def peaked(tmp_path_factory) -> Path:
    """Fig. 1 'symmetric': a pressure peak, inflation only (0 -> 65 mL), two steps."""
    return _bag(tmp_path_factory.mktemp('symmetric'), 'fig1_symmetric.yaml',
                [{'inflate_to_m3': 6.5e-5}], [2.0e-5, 5.0e-5])


def test_a_straight_line_has_no_plateau_and_a_none_sequence_no_switch(linear, tmp_path):
    metrics, text = write_report(linear, tmp_path, figures=False)
    assert metrics['sequence_type'] == 'none'
    # The pressure of two linear segments rises at one slope to the end: no plateau, whatever
    # its end pressure (24.4 kPa) is.
    assert metrics['plateau'] is None
    assert 'does not level off' in metrics['not_applicable']['plateau']
    assert metrics['switch'] is None
    assert 'none takes over' in metrics['not_applicable']['switch']
    # A full cycle: the hysteresis area applies (and is zero: one path both ways).
    assert 'hysteresis_area_j' not in metrics['not_applicable']
    assert abs(metrics['hysteresis_area_j']) < 1e-12
    lines = {line.split(':')[0]: line for line in text.splitlines()}
    assert lines['plateau'].startswith('plateau: does not apply (the pressure does not level')
    assert lines['switch'].startswith('switch: does not apply (no segment')
    saved = json.loads((tmp_path / 'metrics.json').read_text())
    assert saved['plateau'] is None and saved['not_applicable'] == metrics['not_applicable']
    report = (tmp_path / 'report.md').read_text()
    assert '| plateau | does not apply (the pressure does not level off' in report
    assert 'takes over | does not apply' not in report
    assert "inflow) | does not apply (no segment's share" in report


def test_a_falling_curve_has_no_plateau_and_no_deflation_no_hysteresis(peaked, tmp_path):
    metrics, text = write_report(peaked, tmp_path, figures=False)
    assert metrics['sequence_type'] == 'symmetric'
    # The peaked curve's pressure falls after its peak: the end of inflation is no plateau.
    assert metrics['plateau'] is None
    reason = metrics['not_applicable']['plateau']
    assert reason.startswith('the pressure falls during inflation') and 'a peak' in reason
    # A segment takes over: the switch applies.
    assert metrics['switch']['segment_taking_over'] == 'top'
    assert metrics['hysteresis_area_j'] is None and metrics['deflation_recorded'] is False
    assert 'no deflation' in metrics['not_applicable']['hysteresis_area_j']
    assert 'hysteresis area: does not apply (no deflation' in text


def test_the_report_writes_no_empty_figure(linear, tmp_path):
    metrics, _ = write_report(linear, tmp_path)
    # No trigger volumes, no snapshot: no shapes figure (it would be empty).
    assert 'shapes.png' not in metrics['figures'] and not (tmp_path / 'shapes.png').exists()
    assert {'pv.png', 'segments.png', 'volume_split.png', 'timeseries.png'} <= \
        set(metrics['figures'])


def test_compare_says_which_metric_does_not_apply_and_why(linear, peaked):
    _, _, table = compare_bags(linear, peaked)
    rows = {line.split('|')[1].strip(): [c.strip() for c in line.split('|')[2:-1]]
            for line in table.splitlines() if line.startswith('| ')}
    assert rows['switch volume'][1] == 'does not apply'
    assert rows['switch volume'][3] == 'does not apply in A'
    assert rows['plateau pressure (gauge)'][1:] == ['does not apply', 'does not apply',
                                                    'does not apply in A and B']
    assert rows['hysteresis area'][2] == 'does not apply'
    reasons = table.split('Does not apply:')[1].splitlines()
    assert any(line.startswith('- A, switch volume: no segment') for line in reasons)
    assert any(line.startswith('- B, plateau pressure (gauge): the pressure falls')
               for line in reasons)
    assert any(line.startswith('- B, hysteresis area: no deflation') for line in reasons)
