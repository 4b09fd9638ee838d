"""`pose4d train`, `pose4d eval` and `pose4d bench` end to end on a tiny synthetic CAD-60 set."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import write_utkinect
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.cli.main import main as pose4d_main
from pose4d_ros.core.dpm import PartModel, load_model, save_model
from pose4d_ros.core.dpm.model import colour_channel
from pose4d_ros.core.skeleton import PARTS_10, PARTS_14
from pose4d_ros.evaluation import draw as _draw
from pose4d_ros.evaluation import plot as _plot

GROUPS_14 = ['head', 'shoulder', 'elbow', 'wrist', 'hip', 'knee', 'ankle', 'average']
GROUPS_10 = ['head', 'shoulder', 'wrist', 'hip', 'ankle', 'average']
METRICS = ['pck', 'pck@0.2', 'apk', 'error_px']
METRICS_3D = METRICS + ['error_mm', 'within_10cm']  # rows with depth


@pytest.fixture(scope='module')
def tiny_set(tmp_path_factory) -> Path:
    """Two subjects x one video x four frames, rendered by `pose4d synth`."""
    root = tmp_path_factory.mktemp('cad60')
    write_utkinect(root / 'ut')
    out = root / 'set'
    assert pose4d_main(['synth', '--utkinect', str(root / 'ut'), '--out', str(out), '--seed', '5',
                        '--takes', 's01-s02', '--frames', '4', '--stride', '3', '--quiet']) == 0
    return out


def random_model(tree, channels: str, seed: int) -> PartModel:
    rng = np.random.default_rng(seed)
    p, k = len(tree), 2
    springs = np.zeros((p, k, 4), np.float32)
    springs[1:, :, [1, 3]] = 0.1
    anchors = rng.integers(-3, 4, (p, k, 2)).astype(np.int32)
    c = 64 if channels == 'rgbd' else 32
    return PartModel(tree.names, tree.parents, channels, 4,
                     (rng.normal(size=(p, k, 5, 5, c)) * 0.05).astype(np.float32), springs,
                     anchors, np.zeros((p, k, k), np.float32), 32.0, 0.5, (40.0, 80.0),
                     'float' if channels == 'rgbd' else '')


def test_eval_writes_the_table_json(tiny_set: Path, tmp_path: Path, capsys) -> None:
    rgbd, rgb = tmp_path / 'rgbd.npz', tmp_path / 'rgb.npz'
    save_model(random_model(PARTS_10, 'rgbd', 0), rgbd)
    save_model(random_model(PARTS_10, 'rgb', 1), rgb)
    out, plot = tmp_path / 'table.json', tmp_path / 'plots' / 'pck.png'
    # random part models: the mechanics, without the photograph network in their unary
    code = pose4d_main(['eval', str(tiny_set), '--json', str(out), '--model', str(rgbd),
                        '--model', str(rgb), '--plot', str(plot), '--colour-net', 'none'])
    assert code == 0
    table = json.loads(out.read_text())
    assert table['frames'] == 8
    figure = cv2.imread(str(plot))
    assert figure is not None and figure.shape[1] == 3 * _plot.PANEL[0]
    panels = figure[100:]  # below the title and the legend
    for colour in _plot.COLOURS[:5]:  # a curve for every row (5 rows)
        assert (panels == colour).all(axis=2).any(), colour
    assert not (panels == _plot.COLOURS[6]).all(axis=2).any()  # and no other (5: the grey)
    assert not list(plot.parent.glob('.*'))  # no temporary file left
    # the paper's ablation: the detector on each frame alone, then as the graph runs it:
    # the detector with earlier frames, + Kalman filter, + IK (elbows, knees)
    assert list(table['rows']) == ['rgbd', 'rgbd_t', 'rgbd_kf', 'rgbd_kf_ik', 'rgb']
    for name, row in table['rows'].items():
        metrics = METRICS if name == 'rgb' else METRICS_3D
        assert list(row) == metrics + ['cpu_ms', 'search_cells']
        assert 0 < row['cpu_ms']['p50'] <= row['cpu_ms']['p95']
        # the part model's search work a frame, counted (the same on any machine)
        work = row['search_cells']
        assert 0 < work['mean'] <= work['max'] and work['p95'] <= work['max']
        groups = GROUPS_14 if name.endswith('_ik') else GROUPS_10
        for metric in metrics:
            assert list(row[metric]) == groups + (['average7'] if metric.startswith('pck')
                                                  else [])
            for v in row[metric].values():
                assert v is None or np.isfinite(v)
        assert all(0 <= row['pck'][g] <= 100 for g in groups)
        assert row['pck@0.2']['average'] >= row['pck']['average']
    text = capsys.readouterr().out
    assert 'PCK@0.1' in text and 'rgbd' in text and 'APK' in text
    # two models of one kind, without the single-frame pass: each keeps its own rows
    other = tmp_path / 'rgbd_b.npz'
    save_model(random_model(PARTS_10, 'rgbd', 2), other)
    assert pose4d_main(['eval', str(tiny_set), '--json', str(out), '--model', str(rgbd),
                        '--model', str(other), '--no-single-frame']) == 0
    assert list(json.loads(out.read_text())['rows']) == [
        'rgbd_t', 'rgbd_kf', 'rgbd_kf_ik', "rgbd'_t", "rgbd'_kf", "rgbd'_kf_ik"]


def test_train_then_eval_and_bench(tiny_set: Path, tmp_path: Path, capsys) -> None:
    model = tmp_path / 'tiny.npz'
    code = pose4d_main(['train', str(tiny_set), '--out', str(model), '--types', '2',
                        '--rounds', '1', '--masked', '--no-background', '--seed', '3'])
    assert code == 0
    m = load_model(model)
    assert m.part_names == PARTS_10.names and m.channels == 'rgbd' and m.masked_input
    assert m.metadata['seed'] == '3' and 'train_config' in m.metadata
    assert m.calibration is not None and m.calibration.shape == (10, 3)
    # 8 frames are too few right and wrong detections for a logistic: each part's rate
    assert (m.calibration[:, :2] == 0).all() and (np.abs(m.calibration[:, 2]) < 5).all()
    # the joint centres lie behind the rendered body's surface
    assert m.depth_offset_m.shape == (10,) and np.all(np.abs(m.depth_offset_m) < 0.3)
    assert np.median(m.depth_offset_m) > 0.02, m.depth_offset_m
    # the search without depth covers the middle of the trained people's scales
    lo, hi = m.search_range_px
    assert m.scale_range_px[0] <= lo < hi <= m.scale_range_px[1]
    # a look-up per part, the same for a left part and its right twin
    assert m.depth_lookup.shape == (10, 2)
    for i, name in enumerate(m.part_names):
        if name.startswith('left_'):
            twin = m.part_names.index('right_' + name.removeprefix('left_'))
            assert_array_equal(m.depth_lookup[i], m.depth_lookup[twin])
            assert m.depth_offset_m[i] == m.depth_offset_m[twin]
    # the calibration alone, again, on the same frames: the same filters, the same offsets
    # (one calibration subset of the 8 frames), recorded in the metadata
    again = tmp_path / 'again.npz'
    assert pose4d_main(['train', str(tiny_set), '--calibrate', str(model), '--out',
                        str(again)]) == 0
    a = load_model(again)
    assert (a.filters == m.filters).all() and a.metadata['seed'] == '3'
    assert_allclose(a.depth_offset_m, m.depth_offset_m, atol=1e-6)
    assert_array_equal(a.depth_lookup, m.depth_lookup)
    assert_allclose(a.search_range_px, m.search_range_px)
    assert json.loads(a.metadata['calibrated'])['frames'] == 8
    # a narrower search without depth: the middle 60 % of the people's scales
    narrow = tmp_path / 'narrow.npz'
    assert pose4d_main(['train', str(tiny_set), '--calibrate', str(model), '--search-percent',
                        '20', '--out', str(narrow)]) == 0
    lo20, hi20 = load_model(narrow).search_range_px
    assert lo <= lo20 <= hi20 <= hi and (lo20, hi20) != (lo, hi)
    out, drawn = tmp_path / 'table.json', tmp_path / 'drawn'
    assert pose4d_main(['eval', str(tiny_set), '--json', str(out), '--model', str(model),
                        '--draw', str(drawn)]) == 0
    table = json.loads(out.read_text())
    assert list(table['rows']) == ['rgbd', 'rgbd_t', 'rgbd_kf', 'rgbd_kf_ik']
    for row in table['rows']:  # every frame drawn, and the worst and best 8 of 8 as a grid
        assert len(list((drawn / row).glob('*_pck*.jpg'))) == 8
        grid = cv2.imread(str(drawn / f'{row}_worst_best.jpg'))
        assert grid.shape == (2 * _draw.TILE, 8 * _draw.TILE, 3)
    assert not list(drawn.rglob('.*'))
    # trained and tested on the same 8 frames: the parts must mostly be found
    assert table['rows']['rgbd']['pck@0.2']['average'] > 50
    bench = tmp_path / 'bench.json'
    assert pose4d_main(['bench', str(tiny_set), '--json', str(bench), '--model', str(model),
                        '--frames', '4', '--warmup', '2']) == 0
    timings = json.loads(bench.read_text())
    for clock in ('stages_ms', 'wall_ms'):
        stages = timings[clock]
        assert list(stages) == ['foreground', 'detector', 'tracker', 'ik', 'total']
        for st in stages.values():
            assert 0 < st['p50'] <= st['p95']
        assert stages['total']['p50'] >= stages['detector']['p50']
    # the Python calls per frame of each stage, from the profiled pass
    calls = {k: v['calls_per_frame'] for k, v in timings['stages'].items()}
    assert list(calls) == ['foreground', 'detector', 'tracker', 'ik', 'total']
    assert min(calls.values()) > 0
    assert calls['total'] == pytest.approx(sum(list(calls.values())[:4]), abs=0.3)
    # and the search's work, counted in that pass
    assert timings['stages']['detector']['search_cells_per_frame'] > 0
    assert timings['people'] == 'one' and 'people_ms' not in timings
    text = capsys.readouterr().out
    assert 'cores' in text and 'BLAS' in text and 'calls' in text
    assert 'filter positions scored a frame' in text
    # several people: CPU per stage by the number of people tracked in the frame
    assert pose4d_main(['bench', str(tiny_set), '--json', str(bench), '--model', str(model),
                        '--frames', '4', '--warmup', '2', '--people', 'several',
                        '--no-calls']) == 0
    several = json.loads(bench.read_text())
    assert several['people'] == 'several' and 'stages' not in several
    groups = several['people_ms']
    assert all(n.isdigit() for n in groups) and sum(g['frames'] for g in groups.values()) == 4
    for g in groups.values():
        assert g['total']['p50'] >= g['detector']['p50'] > 0


def test_eval_on_an_lspet_layout_scores_elbows_and_knees(tmp_path: Path) -> None:
    import cv2
    import scipy.io

    root = tmp_path / 'lspet'
    (root / 'images').mkdir(parents=True)
    rng = np.random.default_rng(0)
    j = np.zeros((14, 3, 4))
    j[:, :2] = rng.uniform(20, 100, (14, 2, 4))
    j[:, 2] = 1
    scipy.io.savemat(root / 'joints.mat', {'joints': j})
    for i in range(1, 5):
        cv2.imwrite(str(root / 'images' / f'im{i:05d}.jpg'),
                    rng.integers(0, 256, (120, 120, 3)).astype(np.uint8))
    model = tmp_path / 'm14.npz'
    save_model(random_model(PARTS_14, 'rgb', 2), model)
    out = tmp_path / 't.json'
    assert pose4d_main(['eval', str(root), '--range', '2-4', '--json', str(out),
                        '--model', str(model)]) == 0
    table = json.loads(out.read_text())
    assert table['frames'] == 3 and list(table['rows']) == ['rgb']
    assert list(table['rows']['rgb']['pck']) == GROUPS_14 + ['average7']
    # by default the shipped photograph network (core.convnet) gives the row, drawn too
    assert pose4d_main(['eval', str(root), '--range', '2-4', '--json', str(out),
                        '--draw', str(tmp_path / 'draw')]) == 0
    row = json.loads(out.read_text())['rows']['rgb']
    assert list(row['pck']) == GROUPS_14 + ['average7'] and row['cpu_ms']['p50'] > 0
    assert len(list((tmp_path / 'draw' / 'rgb').glob('*.jpg'))) == 3
    # an RGB-D model on photographs: its colour channel alone, in a row named after it, scored
    # exactly as the rgb model made of its filters' colour halves
    rgbd = random_model(PARTS_14, 'rgbd', 2)
    colour = colour_channel(rgbd)
    assert colour.channels == 'rgb' and colour.depth_lookup is None
    np.testing.assert_array_equal(colour.filters, rgbd.filters[..., :colour.filters.shape[-1]])
    save_model(rgbd, tmp_path / 'both14.npz')
    save_model(colour, model)
    assert pose4d_main(['eval', str(root), '--range', '2-4', '--json', str(out),
                        '--model', str(tmp_path / 'both14.npz'), '--model', str(model),
                        '--colour-net', 'none']) == 0
    rows = json.loads(out.read_text())['rows']
    assert list(rows) == ['both14', 'rgb']
    for key in ('pck', 'pck@0.2', 'error_px'):
        assert rows['both14'][key] == rows['rgb'][key]
    # by default, as the detector node, the photograph network joins the part model's unary
    assert pose4d_main(['eval', str(root), '--range', '2-4', '--json', str(out),
                        '--model', str(tmp_path / 'both14.npz')]) == 0
    assert list(json.loads(out.read_text())['rows']) == ['both14+lspet_convnet']


@pytest.mark.parametrize(('argv', 'message'), [
    (['eval', '{set}', '--json', '{tmp}/t.json', '--model', '{tmp}/missing.npz'],
     'missing.npz'),
    (['eval', '{tmp}/nothing', '--json', '{tmp}/t.json'], 'nothing'),
    (['train', '{set}', '--out', '{tmp}/m.txt'], 'must end in .npz'),
    (['bench', '{set}', '--json', '{tmp}/b.json', '--frames', '0'], '--frames'),
    (['eval', '{set}', '--json', '{tmp}/t.json', '--person-scales', '1.2,1'],
     'factors must be ascending'),
    (['eval', '{set}', '--json', '{tmp}/t.json', '--photo-scales', '1.3'],
     '--photo-scales (1.3,): must include 1'),
])
def test_errors_name_the_file_and_exit_2(tiny_set: Path, tmp_path: Path, capsys, argv,
                                         message: str) -> None:
    args = [a.format(set=tiny_set, tmp=tmp_path) for a in argv]
    assert pose4d_main(args) == 2
    assert message in capsys.readouterr().err


def test_eval_and_bench_with_the_peer_score_it_on_the_same_frames(tiny_set: Path, tmp_path: Path,
                                                                  fake_peer, capsys) -> None:
    rgbd = tmp_path / 'rgbd.npz'
    save_model(random_model(PARTS_10, 'rgbd', 0), rgbd)
    out = tmp_path / 'table.json'
    assert pose4d_main(['eval', str(tiny_set), '--json', str(out), '--model', str(rgbd),
                        '--peer', 'mediapipe', '--colour-net', 'none']) == 0
    table = json.loads(out.read_text())
    assert table['frames'] == 8 and table['peer'] == 'fake 1.0'
    assert list(table['rows']) == ['rgbd', 'rgbd_t', 'rgbd_kf', 'rgbd_kf_ik', 'mediapipe']
    for name, row in table['rows'].items():
        searched = [] if name == 'mediapipe' else ['search_cells']
        assert list(row) == METRICS_3D + ['cpu_ms'] + searched
        assert 0 <= row['cpu_ms']['p50'] <= row['cpu_ms']['p95']
    assert list(table['rows']['mediapipe']['pck']) == GROUPS_14 + ['average7']
    assert 'mediapipe' in capsys.readouterr().out
    bench = tmp_path / 'bench.json'
    assert pose4d_main(['bench', str(tiny_set), '--json', str(bench), '--model', str(rgbd),
                        '--frames', '4', '--warmup', '2', '--peer', 'mediapipe']) == 0
    timings = json.loads(bench.read_text())
    assert timings['peer'] == 'fake 1.0'
    assert 0 < timings['peer_ms']['p50'] <= timings['peer_ms']['p95']
    assert 0 < timings['peer_wall_ms']['p50']
    assert timings['ratio_to_peer'] == pytest.approx(
        timings['stages_ms']['total']['p50'] / timings['peer_ms']['p50'], rel=1e-2)


def test_the_peers_depth_offsets_are_fitted_on_one_set_and_give_a_fitted_row(
        tiny_set: Path, tmp_path: Path, fake_peer) -> None:
    offsets, out = tmp_path / 'offsets.json', tmp_path / 'fit.json'
    assert pose4d_main(['eval', str(tiny_set), '--json', str(out), '--peer', 'mediapipe',
                        '--fit-peer-depth', str(offsets)]) == 0
    fitted = json.loads(offsets.read_text())
    assert fitted['peer'] == 'fake 1.0' and set(fitted['joints']) >= {'head', 'left_wrist'}
    assert list(json.loads(out.read_text())['rows']) == ['mediapipe']  # the peer alone
    table = tmp_path / 'table.json'
    assert pose4d_main(['eval', str(tiny_set), '--json', str(table), '--peer', 'mediapipe',
                        '--peer-depth', str(offsets), '--no-single-frame', '--model',
                        'rgbd_10', '--margin', '0.5']) == 0
    rows = json.loads(table.read_text())['rows']
    assert list(rows) == ['rgbd_t', 'rgbd_kf', 'rgbd_kf_ik', 'mediapipe', 'mediapipe_fit']
    assert rows['mediapipe_fit']['pck'] == rows['mediapipe']['pck']  # 3-D only moves


def test_the_peer_starts_a_new_video_where_the_tracker_starts_a_new_track(tiny_set: Path,
                                                                          fake_peer) -> None:
    from pose4d_ros.datasets.cad60 import read_frames
    from pose4d_ros.evaluation.pipeline import peer_rows
    from pose4d_ros.peer import MediaPipePeer

    with MediaPipePeer(fake_peer) as peer:
        row = peer_rows(read_frames(tiny_set), peer)['mediapipe']
    # the stand-in says 1.0 on the first frame of a video: two videos of four frames
    first = [bool(p.confidence[0] == 1.0) for p in row.preds]
    assert first == [True, False, False, False] * 2


def test_without_the_peer_venv_eval_says_make_peer_in_one_line(tiny_set: Path, tmp_path: Path,
                                                               monkeypatch, capsys) -> None:
    monkeypatch.setenv('POSE4D_PEER_PYTHON', str(tmp_path / 'no-venv' / 'python'))
    for verb in ('eval', 'bench'):
        assert pose4d_main([verb, str(tiny_set), '--json', str(tmp_path / 't.json'),
                            '--peer', 'mediapipe']) == 2
        err = capsys.readouterr().err
        assert 'make peer' in err and err.count('\n') == 1, err


def test_frame_pck_scores_each_frame_by_the_table_rule(tiny_set: Path) -> None:
    """A frame predicted exactly scores 100, one shifted by a box size 0, one with some joints
    moved the share of the rest; frames are independent of each other."""
    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.datasets.sources import open_source
    from pose4d_ros.evaluation.pipeline import Row

    frames = list(open_source(str(tiny_set)))[:3]
    names = PARTS_14.names
    row = Row()
    for k, f in enumerate(frames):
        uv, _, _ = f.truth.labelled(names)
        uv = uv.copy()
        if k == 1:
            uv += np.ptp(uv, axis=0).max()
        if k == 2:
            uv[:7] += np.ptp(uv, axis=0).max()
        row.add(JointSet(names, uv, confidence=np.ones(len(names))), 0.0)
    pck = _draw.frame_pck('rgbd', row, frames)
    assert pck[0] == 100 and pck[1] == 0
    assert pck[2] == pytest.approx(100 * 7 / 14)


def test_train_refine_runs_the_detector_and_refuses_too_few_parts(tiny_set: Path,
                                                                   tmp_path: Path,
                                                                   capsys) -> None:
    """`--refine` runs the foreground and the shipped detector over the frames and fits each
    stage on what it found; eight frames hold too few parts per group, which is said, and no
    model file is written; stage counts below one are refused."""
    out = tmp_path / 'refined.npz'
    assert pose4d_main(['train', str(tiny_set), '--refine', 'rgbd_14', '--stages', '1',
                        '--depth-stages', '1', '--out', str(out)]) == 2
    assert 'too few samples to fit a part refiner' in capsys.readouterr().err
    assert not out.exists()
    assert pose4d_main(['train', str(tiny_set), '--refine', 'rgbd_14', '--stages', '0',
                        '--out', str(out)]) == 2
    assert '--stages must be >= 1' in capsys.readouterr().err


def test_a_second_peer_is_one_line_in_the_registry(tiny_set: Path, tmp_path: Path,
                                                   monkeypatch) -> None:
    """`--peer` chooses from `peer.PEERS` and the verbs know no peer by name: a peer that puts
    every joint at the image's centre, registered under a name of its own, gets its row in
    `pose4d eval` and its time in `pose4d bench`; an unknown name is refused."""
    from pose4d_ros import peer as peers
    from pose4d_ros.core.joints import JointSet

    class Centre:
        name, description, last_cpu_s = 'centre', 'every joint at the centre', 0.001
        closed = 0

        def step(self, color, depth_m, intrinsics, *, new_video=False):
            h, w = color.shape[:2]
            return JointSet(peers.NAMES, np.tile([w / 2, h / 2], (len(peers.NAMES), 1)),
                            confidence=np.ones(len(peers.NAMES)))

        def close(self):
            Centre.closed += 1

    monkeypatch.setitem(peers.PEERS, 'centre', Centre)
    out = tmp_path / 'centre.json'
    assert pose4d_main(['eval', str(tiny_set), '--json', str(out), '--peer', 'centre']) == 0
    rows = json.loads(out.read_text())['rows']
    assert list(rows)[-1] == 'centre' and 'rgbd_kf_ik' in rows
    bench = tmp_path / 'bench.json'
    assert pose4d_main(['bench', str(tiny_set), '--json', str(bench), '--peer', 'centre',
                        '--frames', '4', '--warmup', '1']) == 0
    assert json.loads(bench.read_text())['peer'] == 'every joint at the centre'
    assert Centre.closed >= 1
    with pytest.raises(ValueError, match="no peer called 'nobody'"):
        peers.make_peer('nobody')
