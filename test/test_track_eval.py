"""Offline evaluation of tracker and IK on motion (evaluation/tracking.py, evaluation/ik.py,
`pose4d track-eval`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from helpers import write_msr
from numpy.testing import assert_allclose

from pose4d_ros.cli.main import main
from pose4d_ros.core.kinematics import IkConfig
from pose4d_ros.core.slqe import CvConfig, SlqeConfig
from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS, Take
from pose4d_ros.evaluation import ik, tracking

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'utkinect'

# A person facing the sensor in Kinect SDK skeleton space (x to the sensor's left, y up).
TEMPLATE = {
    'hip_center': (0.0, 0.0), 'spine': (0.0, 0.08), 'shoulder_center': (0.0, 0.42),
    'head': (0.0, 0.62), 'left_shoulder': (-0.18, 0.38), 'left_elbow': (-0.24, 0.12),
    'left_wrist': (-0.26, -0.12), 'left_hand': (-0.27, -0.2),
    'right_shoulder': (0.18, 0.38), 'right_elbow': (0.24, 0.12),
    'right_wrist': (0.26, -0.12), 'right_hand': (0.27, -0.2),
    'left_hip': (-0.1, -0.05), 'left_knee': (-0.11, -0.5), 'left_ankle': (-0.12, -0.9),
    'left_foot': (-0.12, -0.95), 'right_hip': (0.1, -0.05), 'right_knee': (0.11, -0.5),
    'right_ankle': (0.12, -0.9), 'right_foot': (0.12, -0.95),
}


def synthetic_take(rng: np.random.Generator, n: int = 120, gap_at: int = 80
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Frame numbers (steps of 2-4, one long gap) and (n, 20, 3) joints in SDK space, metres."""
    steps = rng.choice([2, 4], n - 1)
    steps[gap_at] = 60  # two seconds without frames: a new segment
    frames = 100 + np.concatenate([[0], np.cumsum(steps)])
    t = (frames - frames[0]) / 30.0
    base = np.array([[x, y, 2.4] for x, y in (TEMPLATE[j] for j in UTKINECT_JOINTS)])
    joints = np.repeat(base[None], n, axis=0)
    joints[:, :, 0] += 0.3 * np.sin(0.5 * t)[:, None]  # walking sideways
    for name, sign in (('left', -1.0), ('right', 1.0)):  # waving forearms
        for j in ('wrist', 'hand'):
            k = UTKINECT_JOINTS.index(f'{name}_{j}')
            joints[:, k, 0] += sign * 0.1 * np.sin(2.0 * t)
            joints[:, k, 2] -= 0.1 * (1 - np.cos(2.0 * t))
    return frames, joints


def write_take(path: Path, frames: np.ndarray, joints: np.ndarray) -> None:
    lines = [' '.join([str(f)] + [f'{v:.6f}' for v in row.reshape(-1)])
             for f, row in zip(frames, joints, strict=True)]
    path.write_text('\n'.join(lines) + '\n')


@pytest.fixture
def utkinect_dir(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    d = tmp_path / 'utkinect'
    d.mkdir()
    for take in ('s01_e01', 's07_e01'):
        write_take(d / f'joints_{take}.txt', *synthetic_take(rng))
    return d


def test_corruption_rates_and_seeding() -> None:
    rng = np.random.default_rng(0)
    clean = rng.uniform(0, 300, (2000, 10, 2))
    before = clean.copy()
    noisy, kind = tracking.corrupt(clean, np.random.default_rng(1))
    assert_allclose(clean, before)  # not modified
    assert_allclose(np.mean(kind == 1), 0.10, atol=0.01)
    assert_allclose(np.mean(kind == 2), 0.05, atol=0.01)
    assert np.isnan(noisy[kind == 2]).all()
    d = np.linalg.norm(noisy - clean, axis=-1)
    assert_allclose(np.std((noisy - clean)[kind == 0]), 3.0, rtol=0.05)
    assert d[kind == 1].min() > 20 - 4 * 3 and d[kind == 1].max() < 60 + 4 * 3
    again, _ = tracking.corrupt(clean, np.random.default_rng(1))
    assert_allclose(again, noisy)


def test_split_take_at_gaps() -> None:
    frames, joints = synthetic_take(np.random.default_rng(0))
    segs = tracking.split_take(Take('s03_e02', frames, joints))
    assert [s.name for s in segs] == ['s03_e02/0', 's03_e02/1']
    assert all(s.subject == 3 for s in segs)
    for s in segs:
        assert_allclose(np.diff(s.times), 1 / 30.0, atol=1e-9)
    native = tracking.split_take(Take('s03_e02', frames, joints), native=True)
    assert_allclose(native[0].times, (frames[:81] - frames[0]) / 30.0)
    # Optical frame: SDK x and y flip.
    assert_allclose(native[0].joints[0, 0], joints[0, 0] * [-1, -1, 1])


def test_trackers_reduce_error_on_synthetic_motion(utkinect_dir: Path) -> None:
    segs = tracking.load_segments(utkinect_dir)
    res = tracking.evaluate_tracking(segs, tracking.default_methods(), seed=0)['detected_frames']
    assert res['slqe']['average'] < 0.75 * res['input']['average']
    assert res['slqe']['average'] < res['cv']['average']
    assert res['cv']['coverage'] == 1.0


def test_ik_on_synthetic_motion(utkinect_dir: Path) -> None:
    segs = tracking.load_segments(utkinect_dir)
    lengths = ik.take_lengths(segs, 'take')
    assert_allclose(lengths['s01_e01']['left_leg'], (0.45, 0.4), atol=0.01)
    prior = ik.evaluate_ik(segs, lengths, stride=5)
    depth = ik.evaluate_ik(segs, lengths, depth='capsules', stride=10,
                           config=IkConfig(length_scales=(1.0,)))
    assert prior['flags']['missing'] == 0 and depth['flags']['depth'] > 0
    assert depth['average'] < 40.0, depth
    assert math.isfinite(prior['average'])


def test_track_eval_command(utkinect_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / 'res' / 'track.json'
    rc = main(['track-eval', str(utkinect_dir), '--json', str(out), '--seed', '3',
               '--ik-stride', '6', '--depth-stride', '20', '--no-render', '--quiet'])
    assert rc == 0
    res = json.loads(out.read_text())
    assert res['seed'] == 3 and res['train_subjects'] == [1, 2, 3, 4, 5, 6]
    for split in ('train', 'test', 'test_native_dt'):
        table = res['tracking'][split]['detected_frames']
        assert set(table) == {'input', 'input_held', 'cv', 'cv_gated', 'slqe',
                              'slqe_no_coupling', 'slqe_order2'}
        assert all(math.isfinite(t['average']) for t in table.values())
    for split in ('train', 'test'):  # at 30 fps (the native 7-15 fps is harder: not asserted)
        table = res['tracking'][split]['detected_frames']
        assert table['slqe']['average'] < table['input']['average']
    assert set(res['ik']['test']) == {'prior, lengths take', 'prior, lengths fixed',
                                      'prior shrunk, lengths take',
                                      'depth capsules, lengths take',
                                      'dh: prior, lengths take', 'dh: prior, lengths fixed',
                                      'dh: depth capsules, lengths take'}
    # the same swivel choice: with the prior alone and the lengths of the take, the DH chains
    # put the elbows and knees where the geometric solver does
    ik_test = res['ik']['test']
    assert_allclose(ik_test['dh: prior, lengths take']['average'],
                    ik_test['prior, lengths take']['average'], rtol=1e-6)
    assert not list(out.parent.glob('.track.json.*'))  # no temporary file left


def test_track_eval_ik_only_on_msraction3d(utkinect_dir: Path, tmp_path: Path) -> None:
    msr = tmp_path / 'msr'
    for name in ('a01_s01_e01', 'a14_s07_e01'):
        write_msr(msr, name, frames=40)
    out = tmp_path / 'track.json'
    assert main(['track-eval', str(utkinect_dir), '--msraction3d', str(msr), '--json', str(out),
                 '--no-tracking', '--ik-method', 'dh', '--ik-stride', '6', '--depth-stride',
                 '20', '--no-render', '--quiet']) == 0
    res = json.loads(out.read_text())
    assert res['tracking'] == {}
    assert set(res['ik']['msr_test']) == {'dh: prior, lengths take', 'dh: prior, lengths fixed',
                                          'dh: depth capsules, lengths take'}
    assert res['ik']['msr_test']['dh: prior, lengths take']['n'] == 4 * 14  # 79 frames / 6


def test_track_eval_refuses_bad_input(tmp_path: Path, capsys) -> None:
    assert main(['track-eval', str(tmp_path), '--json', str(tmp_path / 'x.json')]) == 2
    assert 'no joints_sNN_eMM.txt' in capsys.readouterr().err
    assert main(['track-eval', str(tmp_path), '--json', str(tmp_path / 'x.json'),
                 '--train', '1-7']) == 2


@pytest.mark.shared_data
@pytest.mark.skipif(not DATA.is_dir(), reason=f'{DATA} not present (UTKinect skeletons)')
def test_targets_on_real_motion_subset() -> None:
    """SLQE: >= 25 % below the corrupted input and below the CV filter on a test take;
    depth-supported IK below the prior alone."""
    first = tracking.load_segments(DATA, [7])[0]  # s07_e01: its first 50 s at 30 fps
    segs = [tracking.Segment(first.name, first.subject, first.times[:1500], first.joints[:1500])]
    methods = tracking.default_methods(SlqeConfig(), CvConfig())
    res = tracking.evaluate_tracking(segs, methods, seed=0)['detected_frames']
    assert tracking.reduction(res['slqe'], res['input']) >= 0.25, res
    assert res['slqe']['average'] < res['cv']['average']
    lengths = ik.take_lengths(segs, 'take')
    prior = ik.evaluate_ik(segs, lengths, stride=15)
    depth = ik.evaluate_ik(segs, lengths, depth='capsules', stride=30)
    # The IK target (<= 60 mm) holds on the whole test set, not on every take: here only
    # that depth support beats the prior alone.
    assert depth['average'] < prior['average'], (depth, prior)
