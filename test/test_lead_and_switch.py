"""
Who takes the inflow, said the same way by the report, metrics.json, the summary and softseq rates.

Two numbers on the same shares of the inflow (softseq_ros.analysis.metrics): the segment that
first takes 90 % of it ("leads from": who fills first) and the switch, where a segment's share
changes most ("takes over at": where the filling changes hands). softseq rates once said
only the first ("the base leads from 4.5 mL" on rate_inversion) and the report only the second
("the tip takes over at 56.85 mL", a share changing at the end of the inflation, where the tip
draws some 11 mL from the base: an exchange that is now an event, a snap-through whose bins the
shares leave out). Both now say both, from the same metrics: on rate_inversion at its own
0.1 mL/s through its 0.2 mm channel the base passes its peak first and takes the inflow.
"""

import json

import pytest

import softseq_ros
from softseq_ros import cli
from softseq_ros.analysis.report import write_report
from softseq_ros.scene.loader import load_scene

ML = 1e-6


def read_rates(path):
    import csv

    lines = [line for line in path.read_text().splitlines() if not line.startswith('#')]
    comments = [line for line in path.read_text().splitlines() if line.startswith('#')]
    return comments, list(csv.DictReader(lines))


def test_the_report_metrics_summary_and_rates_say_the_same_lead_and_switch(tmp_path, capsys):
    scene = load_scene('rate_inversion')
    bag = tmp_path / 'bag'
    softseq_ros.run(scene, bag, start_time_ns=0)
    metrics, summary = write_report(bag, tmp_path / 'report', figures=False)
    written = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    report = (tmp_path / 'report' / 'report.md').read_text()
    lead, switch = metrics['lead'], metrics['switch']
    assert written['lead'] == lead and written['switch'] == switch
    # The base passes its peak first and takes the inflow: it leads, and takes over there.
    assert lead['segment_leading'] == 'base' and lead['injected_m3'] < 10 * ML
    assert switch['segment_taking_over'] == 'base' and switch['injected_m3'] < 10 * ML
    said_lead = f'base leads the inflow from {lead["injected_m3"] * 1e6:.2f} mL injected'
    said_switch = f'at {switch["injected_m3"] * 1e6:.2f} mL injected, base takes over the inflow'
    assert said_lead in summary and said_switch in summary
    assert f'| base leads from {lead["injected_m3"] * 1e6:.2f} mL |' in report
    assert f'| {switch["injected_m3"] * 1e6:.2f} mL, base takes over |' in report
    # softseq rates at the scene's own point: the same two, under the same names.
    out = tmp_path / 'rates'
    capsys.readouterr()
    assert cli.main(['rates', 'rate_inversion', '--flows', '1e-7', '--radii', '0.2e-3',
                     '--workers', '1', '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    _, (row,) = read_rates(out / 'rates.csv')
    assert row['leading_segment'] == lead['segment_leading']
    assert row['switch_segment'] == switch['segment_taking_over']
    # Sampled otherwise (600 samples a leg against the rig's 20 Hz), within a bin of each.
    assert float(row['lead_injected_m3']) == pytest.approx(lead['injected_m3'],
                                                           abs=lead['bin_m3'])
    assert float(row['switch_injected_m3']) == pytest.approx(switch['injected_m3'], abs=1 * ML)
    assert '| leads (from) | takes over (at) |' in printed
    assert (f'| base ({float(row["lead_injected_m3"]) * 1e6:.1f} mL) | '
            f'base ({float(row["switch_injected_m3"]) * 1e6:.1f} mL) |') in printed
