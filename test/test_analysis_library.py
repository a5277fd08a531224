"""The segment library: nine ordered pairs of three segments, typed as classify types them."""

import io
from pathlib import Path

from figure_checks import capture_figures, laid_out, share_of, titles
from matplotlib.colors import to_hex
import pytest

from softseq_ros.analysis.library import LibraryError, library_entries, write_library
from softseq_ros.quasistatic.equilibrium import classify
from softseq_ros.quasistatic.solve import equilibrium_map
from softseq_ros.scene.loader import load_scene

LIBRARY = Path(__file__).resolve().parents[1] / 'config' / 'library'


def test_three_segments_give_nine_pairs_typed_like_classify(tmp_path, monkeypatch):
    from softseq_ros.analysis import library

    drawn = capture_figures(monkeypatch, library)
    progress = io.StringIO()
    results, table = write_library(LIBRARY, tmp_path, processes=2, progress=progress)
    names = sorted(p.stem for p in LIBRARY.glob('*.csv'))
    assert len(names) == 3
    assert [tuple(r['segments']) for r in results] == [(a, b) for a in names for b in names]
    assert progress.getvalue().count('assembled') == 9
    types = set()
    for result in results:
        base, tip = result['segments']
        scene = tmp_path / f'{base}__{tip}.yaml'
        scene.write_text(f"""name: pair
segments:
  - {{name: base, length_m: 0.111, table: {LIBRARY / (base + '.csv')}}}
  - {{name: tip, length_m: 0.111, table: {LIBRARY / (tip + '.csv')}}}
pump:
  flow_rate_m3_per_s: 5.0e-8
  legs: [{{inflate_to_m3: 1.0e-5}}, {{deflate_to_m3: 0.0}}]
""")
        expected = classify(equilibrium_map(load_scene(scene).segments))
        assert result['sequence_type'] == expected, result['segments']
        # The sweep's own metrics reach the same verdict by the rules applied to its path.
        assert result['sequence_type_of_sweep'] == expected, result['segments']
        assert (len(result['snaps']) > 0) == (expected == 'asymmetric')
        for snap in result['snaps']:
            # Under volume control a snap on inflation leaves a pressure peak (the pressure
            # falls), one on deflation a valley (it rises): the figure's arrows point so.
            fall = snap['pressure_before_pa'] - snap['pressure_after_pa']
            assert fall > 0 if snap['direction'] == 'inflation' else fall < 0, snap
        types.add(expected)
    assert types == {'none', 'partial', 'symmetric', 'asymmetric'}
    assert table.count('\n') == 2 + 9
    # The figure in the paper style: no title, 300 dpi, cropped, each type's colour drawn.
    [fig] = drawn
    assert not titles(fig)
    pixels = laid_out(tmp_path / 'library.png')
    for colour in library.TYPE_COLOURS.values():
        assert share_of(pixels, to_hex(colour)) > 1e-4, colour


def test_a_folder_without_tables_or_lengths_is_refused(tmp_path):
    with pytest.raises(LibraryError, match='no segment tables'):
        library_entries(tmp_path)
    (tmp_path / 'a.csv').write_text('volume_m3,pressure_pa,curvature_per_m\n0,0,0\n1e-6,1000,0\n')
    with pytest.raises(LibraryError, match='--length-m'):
        library_entries(tmp_path)
    assert library_entries(tmp_path, length_m=0.1)[0].length_m == 0.1


def test_triples_add_every_ordered_triple(tmp_path):
    source = tmp_path / 'two'
    source.mkdir()
    for name in ('paper_bottom', 'paper_top'):
        (source / f'{name}.csv').write_text((LIBRARY / f'{name}.csv').read_text())
    results, _ = write_library(source, tmp_path / 'out', triples=True, processes=2,
                               progress=None)
    triples = [r for r in results if len(r['segments']) == 3]
    assert len(results) == 4 + 8 and len(triples) == 8
    for result in triples:
        assert result['sequence_type'] == result['sequence_type_of_sweep']
    # Three identical monotone segments share the inflow equally: no sequence.
    same = next(r for r in triples if r['segments'] == ['paper_top'] * 3)
    assert same['sequence_type'] == 'none'
    assert any(r['sequence_type'] == 'partial' for r in triples)
