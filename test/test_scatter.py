"""
softseq scatter: the sequence under parameter scatter, against closed forms and as a user runs it.

The closed-form pair (scenes.flip_document): a linear bottom segment that ends at P_MAX and a
neo-Hookean balloon top whose pressure peaks at p* = (12/7) 7^(-1/6) mu H / R. Where p* < P_MAX
the top passes its peak and empties the bottom into itself (symmetric); where p* > P_MAX the
bottom ends first and the top only takes over (partial). So the type flips at
H_FLIP = P_MAX R / ((12/7) 7^(-1/6) mu), and with H normal the probability of the symmetric
type is the normal CDF there.
"""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from scenes import FLIP_H, FLIP_STIFFNESS, flip_document
from scipy.stats import binomtest, norm

from softseq_ros.analysis import scatter
from softseq_ros.cli import main
from softseq_ros.scene.loader import scene_from_dict

H_FLIP, STIFFNESS = FLIP_H, FLIP_STIFFNESS


@pytest.fixture(scope='module')
def flip_scene():
    return scene_from_dict(flip_document())


@pytest.fixture
def flip_file(tmp_path):
    import yaml

    path = tmp_path / 'flip.yaml'
    path.write_text(yaml.safe_dump(flip_document()))
    return path


def test_the_type_flips_where_the_closed_form_says():
    for factor, kind in ((0.995, 'symmetric'), (1.005, 'partial')):
        scene = scene_from_dict(flip_document(H_FLIP * factor))
        assert scatter.measure(scene.segments)['sequence_type'] == kind


def test_the_probability_of_the_type_is_the_normal_cdf_at_the_flip(flip_scene):
    mean, std = 0.97 * H_FLIP, 0.05 * H_FLIP
    parameters = scatter.parameters_of(flip_scene,
                                       {'top.thickness_m': f'normal:{mean!r},{std!r}'})
    result = scatter.run_scatter(flip_scene, parameters, samples=600, sobol=0, workers=1,
                                 confidence=0.99)
    expected = float(norm.cdf((H_FLIP - mean) / std))   # 0.726
    symmetric = result.summary['sequence_type']['symmetric']
    low, high = symmetric['interval']
    assert low <= expected <= high, (expected, symmetric)
    assert high - low < 0.12   # the interval is no vacuous one
    # Every sample is one of the two types, and on the side of the flip its thickness says.
    assert symmetric['count'] + result.summary['sequence_type']['partial']['count'] == 600
    for sample in result.samples:
        (thickness,) = sample['values']
        if abs(thickness / H_FLIP - 1.0) > 0.002:
            assert sample['sequence_type'] == ('symmetric' if thickness < H_FLIP
                                               else 'partial')


def test_the_wilson_interval_is_scipys():
    for count, samples in ((0, 50), (17, 40), (400, 400), (726, 1000)):
        ours = scatter.wilson_interval(count, samples, 0.95)
        theirs = binomtest(count, samples).proportion_ci(0.95, method='wilson')
        assert ours == pytest.approx((theirs.low, theirs.high), abs=1e-12)


def test_first_order_sobol_indices_of_a_linear_function_match_their_closed_form():
    distributions = [scatter.parse_distribution('a', 'normal:1,0.5', 0.0),
                     scatter.parse_distribution('b', 'uniform:-1,3', 0.0),
                     scatter.parse_distribution('c', 'normal:100%', 2.0)]
    slopes = np.array([2.0, -1.0, 0.5])
    inputs = scatter.sobol_inputs(3, 4096, seed=3)
    x = np.column_stack([d.values(inputs[:, i]) for i, d in enumerate(distributions)])
    shares = slopes**2 * np.array([d.variance for d in distributions])
    exact = shares / shares.sum()   # 0.3, 0.4, 0.3
    indices = scatter.sobol_indices(['a', 'b', 'c'], list(x @ slopes), seed=3)
    for name, expected in zip('abc', exact):
        assert indices[name]['first_order'] == pytest.approx(expected, abs=0.03)
        # Additive: nothing is left to interactions, the total index is the first-order one.
        assert indices[name]['total'] == pytest.approx(expected, abs=0.03)
    # An output that does not move, or is missing somewhere, has no indices, and says why.
    assert 'reason' in scatter.sobol_indices(['a'], [1.0] * 8)
    assert 'reason' in scatter.sobol_indices(['a'], [1.0, None] * 4)


BAD_INPUTS = {
    'negative_spread': (['--vary', 'top.thickness_m=normal:2e-3,-1e-4'],
                        'top.thickness_m: the standard deviation must be > 0'),
    'negative_percent': (['--vary', 'top.thickness_m=uniform:-5%'],
                         'top.thickness_m: the spread must be > 0 %'),
    'nan_mean': (['--vary', 'top.thickness_m=normal:nan,1e-4'],
                 'top.thickness_m: must be a finite number'),
    'nan_noise': (['--vary', 'top.thickness_m=nan'], 'top.thickness_m'),
    'unknown_key': (['--vary', 'top.thickness_mm=normal:5%'],
                    "segment top (balloon) has no 'thickness_mm'; it has"),
    'unknown_segment': (['--vary', 'middle.thickness_m=normal:5%'],
                        "the scene has no segment 'middle' (it has bottom, top)"),
    'table_key_of_a_law': (['--vary', 'top.pressure_scale=normal:5%'],
                           "has no 'pressure_scale'"),
    'reaches_a_refused_value': (['--vary', 'top.thickness_m=uniform:-1e-3,3e-3'],
                                'its lowest draw, -0.001, is refused'),
    'empty_uniform': (['--vary', 'top.thickness_m=uniform:3e-3,2e-3'],
                      'the high end must exceed the low end'),
    'no_distribution': (['--vary', 'top.thickness_m'], 'is not NAME=DISTRIBUTION'),
    'nothing_varied': ([], '--vary: nothing to vary'),
    'width_nan': (['--vary', 'top.thickness_m=normal:5%', '--until-width', 'nan'],
                  '--until-width'),
    'width_above_one': (['--vary', 'top.thickness_m=normal:5%', '--until-width', '2'],
                        '--until-width'),
    'samples_zero': (['--vary', 'top.thickness_m=normal:5%', '--samples', '0'], '--samples'),
    'sobol_not_a_power_of_two': (['--vary', 'top.thickness_m=normal:5%', '--sobol', '48'],
                                 '--sobol'),
    'confidence_above_one': (['--vary', 'top.thickness_m=normal:5%', '--confidence', '1.5'],
                             '--confidence'),
    'workers_zero': (['--vary', 'top.thickness_m=normal:5%', '--workers', '0'], '--workers'),
    'fem_points_one': (['--vary', 'top.thickness_m=normal:5%', '--fem-points', '1'],
                       '--fem-points: unit cells per drawn geometry key'),
}


CORRELATE = ['--vary', 'top.thickness_m=normal:5%', '--vary', 'top.radius_m=normal:1%',
             '--vary', 'bottom.stiffness_pa_per_m3=uniform:2%']
BAD_INPUTS.update({
    'correlate_no_pair': ([*CORRELATE, '--correlate', 'top.thickness_m=0.5'],
                          "--correlate: 'top.thickness_m=0.5' is not NAME,NAME=RHO"),
    'correlate_above_one': ([*CORRELATE, '--correlate', 'top.thickness_m,top.radius_m=1.5'],
                            '--correlate top.thickness_m,top.radius_m: a correlation from -1 '
                            'to 1, got 1.5'),
    'correlate_nan': ([*CORRELATE, '--correlate', 'top.thickness_m,top.radius_m=nan'],
                      '--correlate top.thickness_m,top.radius_m: must be a finite number'),
    'correlate_itself': ([*CORRELATE, '--correlate', 'top.radius_m,top.radius_m=0.5'],
                         'a parameter is not correlated with itself'),
    'correlate_twice': ([*CORRELATE, '--correlate', 'top.radius_m,top.thickness_m=0.5',
                         '--correlate', 'top.thickness_m,top.radius_m=0.4'], 'given twice'),
    'correlate_not_varied': ([*CORRELATE, '--correlate', 'top.thickness_m,top.max_stretch=0.5'],
                             'top.max_stretch is not varied (the parameters: top.thickness_m, '),
    'correlate_inconsistent': ([*CORRELATE,
                                '--correlate', 'top.thickness_m,top.radius_m=-0.9',
                                '--correlate', 'top.radius_m,bottom.stiffness_pa_per_m3=-0.9',
                                '--correlate', 'top.thickness_m,bottom.stiffness_pa_per_m3=-0.9'],
                               'cannot hold together (their matrix has the eigenvalue -0.8 < 0)'),
})


@pytest.mark.parametrize('case', sorted(BAD_INPUTS))
def test_bad_input_is_refused_in_one_line_before_anything_runs(case, tmp_path, capsys):
    words, expected = BAD_INPUTS[case]
    out = tmp_path / 'out'
    code = main(['scatter', 'fig1_symmetric', *words, '--out', str(out), '--quiet'])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('softseq scatter: error: '), err
    assert expected in lines[0], lines[0]
    assert not out.exists()


def test_a_spec_file_is_read_and_its_mistakes_named(tmp_path, flip_scene):
    spec = tmp_path / 'spec.yaml'
    spec.write_text('vary:\n  top.thickness_m: normal:5%\n  bottom.stiffness_pa_per_m3: '
                    'uniform:4.5e8,5.5e8\n')
    vary = scatter.read_vary(['top.radius_m=normal:1%'], spec)
    assert vary == {'top.radius_m': 'normal:1%', 'top.thickness_m': 'normal:5%',
                    'bottom.stiffness_pa_per_m3': 'uniform:4.5e8,5.5e8'}
    parameters = scatter.parameters_of(flip_scene, vary)
    assert [p.distribution.kind for p in parameters] == ['normal', 'normal', 'uniform']
    assert parameters[1].distribution.b == pytest.approx(0.05 * H_FLIP)
    with pytest.raises(scatter.ScatterError, match='given on the command line and in --spec'):
        scatter.read_vary(['top.thickness_m=normal:1%'], spec)
    assert scatter.read_correlate(['top.radius_m,top.thickness_m=0.3'], spec) == {
        ('top.radius_m', 'top.thickness_m'): 0.3}
    spec.write_text(spec.read_text() + 'correlate:\n  top.thickness_m,bottom.stiffness_pa_per_m3: '
                    '0.5\n')
    assert scatter.read_correlate(['top.radius_m,top.thickness_m=0.3'], spec) == {
        ('top.radius_m', 'top.thickness_m'): 0.3,
        ('top.thickness_m', 'bottom.stiffness_pa_per_m3'): 0.5}
    assert len(scatter.read_vary([], spec)) == 2
    spec.write_text('parameters: {}\n')
    with pytest.raises(scatter.ScatterError, match='must be a mapping with the key vary'):
        scatter.read_vary([], spec)
    with pytest.raises(scatter.ScatterError, match='cannot read it'):
        scatter.read_vary([], tmp_path / 'missing.yaml')


def test_the_command_end_to_end(flip_file, tmp_path):
    out = tmp_path / 'scatter'
    words = [sys.executable, '-m', 'softseq_ros.cli', 'scatter', str(flip_file),
             '--vary', f'top.thickness_m=normal:{H_FLIP!r},{0.03 * H_FLIP!r}',
             '--vary', 'bottom.stiffness_pa_per_m3=uniform:2%',
             '--samples', '100', '--sobol', '8', '--seed', '7', '--out', str(out)]
    done = subprocess.run([*words, '--workers', '1'], capture_output=True, text=True,
                          timeout=300, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in out.iterdir()) == ['scatter.json', 'scatter.png',
                                                    'summary.txt']
    data = json.loads((out / 'scatter.json').read_text())
    assert data['summary']['samples'] == 100 and len(data['samples']) == 100
    assert data['sobol']['evaluations'] == 8 * (2 + 2) == len(data['sobol_samples'])
    chances = data['summary']['sequence_type']
    assert sum(p['count'] for p in chances.values()) == 100
    assert chances['symmetric']['count'] > 0 and chances['partial']['count'] > 0
    for p in chances.values():
        assert p['interval'][0] <= p['probability'] <= p['interval'][1]
    stiffness = np.array([s['values'][1] for s in data['samples']])
    assert stiffness.min() >= 0.98 * STIFFNESS and stiffness.max() <= 1.02 * STIFFNESS
    # The thickness decides the type: its indices name it, the stiffness barely counts.
    indices = data['sobol']['indices']['is_symmetric']
    assert indices['top.thickness_m']['total'] > 0.5 > indices['bottom.stiffness_pa_per_m3'][
        'total']
    text = (out / 'summary.txt').read_text()
    assert text == done.stdout
    assert 'sequence type: ' in text and 'top.thickness_m' in text
    assert (out / 'scatter.png').stat().st_size > 10_000
    # The same seed on two worker processes: the same samples, in the same order.
    again = tmp_path / 'again'
    words[-1] = str(again)
    done = subprocess.run([*words, '--workers', '2', '--quiet'], capture_output=True,
                          text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ''
    assert json.loads((again / 'scatter.json').read_text())['samples'] == data['samples']


def test_a_run_stops_at_the_first_check_where_every_interval_is_narrow_enough(flip_scene):
    parameters = scatter.parameters_of(flip_scene,
                                       {'top.thickness_m': f'normal:{H_FLIP!r},'
                                                           f'{0.05 * H_FLIP!r}'})
    width = 0.15
    stopped = scatter.run_scatter(flip_scene, parameters, samples=1000, until_width=width,
                                  sobol=0, workers=2)
    count = len(stopped.samples)
    assert count % scatter.CHECK_EVERY == 0 and count < 1000
    assert [s['index'] for s in stopped.samples] == list(range(count))
    assert scatter.widest_interval(stopped.summary) <= width
    assert stopped.stop['reached'] is True
    # One check earlier it was not narrow enough: the run stopped at the first check it could.
    earlier = scatter.summarise(stopped.samples[:-scatter.CHECK_EVERY])
    assert scatter.widest_interval(earlier) > width
    # A near-even split needs about (1.96 / width)^2 samples: 171 here.
    assert 150 <= count <= 250
    # The samples are the first ones of a run without the rule: stopping changed none.
    whole = scatter.run_scatter(flip_scene, parameters, samples=count, sobol=0, workers=1)
    assert whole.samples == stopped.samples
    # Asked for a width the samples cannot reach, it runs them all and says so.
    short = scatter.run_scatter(flip_scene, parameters, samples=100, until_width=0.01,
                                sobol=0, workers=1)
    assert len(short.samples) == 100 and short.stop['reached'] is False
    assert math.isclose(short.stop['widest_interval'], scatter.widest_interval(short.summary))


# ------------------------------------------------------------------------------ correlated draws

def _fisher_interval(r: float, n: int, z: float, scale: float = 1.0) -> tuple[float, float]:
    """The interval of a correlation's estimate ``r`` over ``n`` samples (Fisher's z)."""
    half = scale * z / math.sqrt(n - 3)
    return math.tanh(math.atanh(r) - half), math.tanh(math.atanh(r) + half)


def test_correlated_draws_have_the_asked_correlation_and_keep_their_distributions(flip_scene):
    from scipy.stats import spearmanr

    vary = {'top.thickness_m': 'normal:5%', 'bottom.stiffness_pa_per_m3': 'normal:5%',
            'top.radius_m': 'uniform:2%', 'top.material.shear_modulus_pa': 'normal:3%'}
    parameters = scatter.parameters_of(flip_scene, vary)
    correlation = scatter.correlation_of(parameters, {
        ('top.thickness_m', 'bottom.stiffness_pa_per_m3'): 0.8,
        ('top.radius_m', 'top.thickness_m'): -0.5})
    assert correlation.groups == ((0, 1, 2),)
    n = 4000
    inputs = scatter.sample_inputs(5, 0, n, 4)
    values = scatter.ScatterModel.of(flip_scene, parameters, correlation).values_at(inputs)
    alone = scatter.ScatterModel.of(flip_scene, parameters).values_at(inputs)
    z = norm.ppf(0.995)
    # Two normal parameters: their correlation is rho, within the estimate's interval.
    low, high = _fisher_interval(np.corrcoef(values[:, 0], values[:, 1])[0, 1], n, z)
    assert low <= 0.8 <= high
    # A uniform one: rank correlation (6/pi) asin(rho/2) (Spearman's standard error is about
    # 1.06 times Fisher's); and none where none was asked (its matrix entry is 0).
    rank = (6 / math.pi) * math.asin(-0.5 / 2)
    low, high = _fisher_interval(spearmanr(values[:, 2], values[:, 0])[0], n, z, 1.06)
    assert low <= rank <= high
    low, high = _fisher_interval(np.corrcoef(values[:, 2], values[:, 1])[0, 1], n, z, 1.06)
    assert low <= 0.0 <= high
    # Each keeps its distribution: the normals' means and deviations, the uniform's range.
    for k in (0, 1):
        nominal = parameters[k].nominal
        assert abs(values[:, k].mean() / nominal - 1) < z * 0.05 / math.sqrt(n)
        assert values[:, k].std() / nominal == pytest.approx(0.05, rel=0.05)
    radius = parameters[2].nominal
    assert 0.98 * radius <= values[:, 2].min() and values[:, 2].max() <= 1.02 * radius
    # A parameter outside every correlation draws as it did without any.
    np.testing.assert_array_equal(values[:, 3], alone[:, 3])


@pytest.mark.parametrize('rho, expected', [(0.8, 0.8286), (1.0, 1.0)])
def test_a_correlated_flip_has_the_closed_form_probability(flip_scene, rho, expected):
    # The type flips where the balloon's peak p* (proportional to H) meets the bottom's end
    # P_MAX (proportional to its stiffness k): symmetric where H / H_FLIP < k / k0. With both
    # normal (means 0.97 and 1, deviations 0.05 of them) and their correlation rho, the
    # probability is Phi(0.03 / (0.05 sqrt(2 (1 - rho)))): 0.829 at 0.8 (0.664 independent),
    # 1 at rho = 1, a shared factor (one batch of rubber for both).
    mean, std = 0.97 * H_FLIP, 0.05 * H_FLIP
    parameters = scatter.parameters_of(flip_scene, {
        'top.thickness_m': f'normal:{mean!r},{std!r}',
        'bottom.stiffness_pa_per_m3': 'normal:5%'})
    correlation = scatter.correlation_of(
        parameters, {('top.thickness_m', 'bottom.stiffness_pa_per_m3'): rho})
    samples = 600 if rho < 1 else 100
    result = scatter.run_scatter(flip_scene, parameters, samples=samples, sobol=0, workers=1,
                                 confidence=0.99, correlation=correlation)
    if rho < 1:
        assert float(norm.cdf(0.03 / (0.05 * math.sqrt(2 * (1 - rho))))) == pytest.approx(
            expected, abs=1e-4)
    symmetric = result.summary['sequence_type']['symmetric']
    low, high = symmetric['interval']
    assert low <= expected <= high, symmetric
    independent = float(norm.cdf(0.03 / (0.05 * math.sqrt(2))))
    assert not low <= independent <= high   # the correlation is what moved it
    assert result.to_dict()['correlations'] == [
        {'parameters': ['top.thickness_m', 'bottom.stiffness_pa_per_m3'], 'rho': rho}]


def test_sobol_indices_of_correlated_parameters_are_their_groups(flip_scene):
    # Y = 2a + b + c/2, a and b normal with correlation 0.6 (one group), c uniform alone: the
    # group's index is Var(2a + b) / Var(Y), with Var(2a + b) = 4 sa^2 + sb^2 + 4 rho sa sb.
    distributions = [scatter.parse_distribution('a', 'normal:1,0.5', 0.0),
                     scatter.parse_distribution('b', 'normal:0,1', 0.0),
                     scatter.parse_distribution('c', 'uniform:-1,3', 0.0)]
    parameters = [scatter.Parameter(n, 0, (n,), 0.0, d) for n, d in zip('abc', distributions)]
    correlation = scatter.correlation_of(parameters, {('a', 'b'): 0.6})
    groups = correlation.group_names(['a', 'b', 'c'])
    assert groups == ['a+b', 'a+b', 'c']
    inputs = scatter.sobol_inputs(3, 4096, seed=3, groups=groups)
    assert inputs.shape == (4096 * (2 + 2), 3)
    mixed = correlation.mix(inputs)
    x = np.column_stack([d.values(mixed[:, i]) for i, d in enumerate(distributions)])
    pair = 4 * 0.25 + 1.0 + 4 * 0.6 * 0.5 * 1.0
    exact = {'a+b': pair / (pair + 0.25 * 16 / 12), 'c': 0.25 * 16 / 12 / (pair + 0.25 * 16 / 12)}
    indices = scatter.sobol_indices(['a', 'b', 'c'], list(x @ [2.0, 1.0, 0.5]), seed=3,
                                    groups=groups)
    assert set(indices) == set(exact)
    for name, expected in exact.items():
        assert indices[name]['first_order'] == pytest.approx(expected, abs=0.03)
        assert indices[name]['total'] == pytest.approx(expected, abs=0.03)


def test_a_correlated_run_on_the_command_line_names_its_groups(flip_file, tmp_path, capsys):
    out = tmp_path / 'out'
    code = main(['scatter', str(flip_file), '--vary', 'top.thickness_m=normal:5%',
                 '--vary', 'bottom.stiffness_pa_per_m3=normal:5%',
                 '--vary', 'top.radius_m=uniform:1%',
                 '--correlate', 'top.thickness_m,bottom.stiffness_pa_per_m3=0.9',
                 '--samples', '50', '--sobol', '8', '--workers', '1', '--quiet',
                 '--out', str(out)])
    printed = capsys.readouterr().out
    assert code == 0
    assert ('correlated (their normal scores): top.thickness_m with '
            'bottom.stiffness_pa_per_m3 0.9') in printed
    data = json.loads((out / 'scatter.json').read_text())
    # Two groups: the correlated pair and the radius; the design is 8 x (2 + 2) samples.
    assert data['sobol']['evaluations'] == 8 * (2 + 2)
    indices = data['sobol']['indices']['is_symmetric']
    assert set(indices) == {'top.thickness_m+bottom.stiffness_pa_per_m3', 'top.radius_m'}
    values = np.array([s['values'][:2] for s in data['samples']])
    assert np.corrcoef(values.T)[0, 1] > 0.7
    assert (out / 'scatter.png').stat().st_size > 10_000


def test_one_correlated_group_of_every_parameter_has_no_sobol_indices_and_says_why(flip_scene):
    parameters = scatter.parameters_of(flip_scene, {'top.thickness_m': 'normal:5%',
                                                    'bottom.stiffness_pa_per_m3': 'normal:5%'})
    correlation = scatter.correlation_of(
        parameters, {('top.thickness_m', 'bottom.stiffness_pa_per_m3'): 0.5})
    result = scatter.run_scatter(flip_scene, parameters, samples=10, sobol=8, workers=1,
                                 correlation=correlation)
    assert result.sobol == {} and result.sobol_samples == []
    assert result.notes == [scatter.ONE_GROUP]


# ------------------------------------------------------------------------------ other supplies

def test_a_network_scene_is_scattered_quasi_statically_and_says_so():
    import softseq_ros

    vary = {'top.material.shear_modulus_pa': 'normal:3%'}
    results = []
    for name in ('fig1_asymmetric_dynamic', 'fig1_asymmetric'):
        scene = softseq_ros.load_scene(name)
        results.append(scatter.run_scatter(scene, scatter.parameters_of(scene, vary),
                                           samples=10, sobol=0, workers=1))
    dynamic, syringe = results
    assert dynamic.notes == [
        'fig1_asymmetric_dynamic has a fluid network; it is not sampled: every sample is '
        'classified and measured quasi-statically, as softseq classify does it, not in time '
        "at the pump's rate (softseq rates maps what the network's rate does)"]
    assert syringe.notes == []
    # The same segments without the network: the same samples, number for number.
    assert dynamic.samples == syringe.samples
    assert dynamic.to_dict()['notes'] == dynamic.notes


def test_a_scene_behind_a_regulator_is_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / 'out'
    code = main(['scatter', 'fig1_regulator_quasistatic', '--vary',
                 'top.material.shear_modulus_pa=normal:3%', '--out', str(out), '--quiet'])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith('softseq scatter: error: ') and lines[0].endswith(
        'fig1_regulator_quasistatic.yaml: supply.regulator: scatter classifies segments sharing '
        'the volume a syringe pushes; behind a regulator each segment is an independent '
        'hysteron (softseq graph shows its flips): scatter the pair without its regulator')
    assert not out.exists()
