"""The MediaPipe peer: its protocol and joint mapping with a fake worker (always), and the real
MediaPipe 0.10.21 on the bundled bag (only where `make peer` has built .venv-peer)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pose4d_ros import peer
from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import backproject, cad60_intrinsics, robust_depth
from pose4d_ros.core.skeleton import SKELETON_14, ground_truth_name

REPO = Path(__file__).resolve().parents[1]


def frame(red: int, blue: int = 1, size: tuple[int, int] = (320, 240)) -> np.ndarray:
    rgb = np.zeros((size[1], size[0], 3), np.uint8)
    rgb[0, 0] = (red, 0, blue)
    return rgb


def test_mapping_takes_the_ears_midpoint_and_the_limb_landmarks() -> None:
    lm = np.zeros((33, 3))
    lm[:, 0], lm[:, 1], lm[:, 2] = np.arange(33), 100 + np.arange(33), np.linspace(0, 1, 33)
    uv, conf = peer.joints_from_landmarks(lm)
    assert peer.NAMES == tuple(n for n in SKELETON_14 if n != 'neck')
    assert_allclose(uv[peer.NAMES.index('head')], (7.5, 107.5))  # ears 7 and 8
    assert_allclose(conf[peer.NAMES.index('head')], (lm[7, 2] + lm[8, 2]) / 2, rtol=1e-6)
    for name, index in (('left_shoulder', 11), ('right_shoulder', 12), ('left_elbow', 13),
                        ('right_elbow', 14), ('left_wrist', 15), ('right_wrist', 16),
                        ('left_hip', 23), ('right_hip', 24), ('left_knee', 25),
                        ('right_knee', 26), ('left_ankle', 27), ('right_ankle', 28)):
        assert_allclose(uv[peer.NAMES.index(name)], lm[index, :2])
        assert_allclose(conf[peer.NAMES.index(name)], lm[index, 2], rtol=1e-6)
    with pytest.raises(ValueError, match='33, 3'):
        peer.joints_from_landmarks(lm[:17])


def test_fake_worker_round_trip_lifts_with_the_detectors_depth_look_up(fake_peer) -> None:
    intr = cad60_intrinsics()
    rng = np.random.default_rng(0)
    depth = rng.uniform(1.5, 3.0, (240, 320)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] = np.nan
    with peer.MediaPipePeer() as p:  # the stand-in, through POSE4D_PEER_PYTHON
        assert p.description == 'fake 1.0'
        first = p.step(frame(40), depth, intr, new_video=True)
        second = p.step(frame(41), depth, intr)
        none = p.step(frame(42, blue=0), depth, intr)
        assert p.last_cpu_s >= 0.0
        wide = p.landmarks(frame(0, size=(640, 480)))
    assert first.names == peer.NAMES
    lm = np.stack([319.0 - np.arange(33), 40.0 + 2 * np.arange(33)], axis=1)
    uv, _ = peer.joints_from_landmarks(np.column_stack([lm, np.ones(33)]))
    assert_allclose(first.uv, uv)
    expected = backproject(uv, robust_depth(depth, uv, radius=3), intr)
    assert_allclose(first.xyz, expected)
    assert np.isfinite(first.xyz).all()
    assert (first.source == cj.DETECTED).all()
    assert_allclose(first.confidence, 1.0)  # reset: the first frame of a video
    assert_allclose(second.confidence, 0.25)
    assert_allclose(second.uv[:, 1], uv[:, 1] + 1)
    assert (none.source == cj.MISSING).all()
    assert_allclose(wide[:, 0], 639.0 - np.arange(33))


def test_without_depth_the_joints_have_no_3d(fake_peer) -> None:
    with peer.MediaPipePeer(fake_peer) as p:
        js = p.step(frame(40), None, None)
    assert np.isfinite(js.uv).all() and np.isnan(js.xyz).all()


def test_a_failing_worker_is_reported_with_its_last_words() -> None:
    crash = [sys.executable, '-c', 'import sys; sys.stderr.write("no module mediapipe\\n"); '
             'sys.exit(3)']
    with pytest.raises(ValueError, match='stopped: no module mediapipe'):
        peer.MediaPipePeer(crash)


def test_without_the_peer_venv_the_error_says_make_peer(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv('POSE4D_PEER_PYTHON', str(tmp_path / 'nothing' / 'python'))
    with pytest.raises(ValueError, match='make peer') as err:
        peer.worker_command()
    assert '\n' not in str(err.value)


@pytest.fixture
def real_peer() -> list[str]:
    try:
        return peer.worker_command()
    except ValueError as exc:
        pytest.skip(f'needs MediaPipe in .venv-peer (`make peer`): {exc}')


def test_real_mediapipe_finds_the_sample_bags_person_on_their_own_sides(real_peer) -> None:
    from pose4d_ros.datasets.cad60_bag import read_frames

    frames = [f for _, f in zip(range(8), read_frames(REPO / 'bags' / 'sample'), strict=False)]
    pixel, metric, own_side = [], [], []
    with peer.MediaPipePeer(real_peer) as p:
        assert p.description.startswith('mediapipe 0.10.21 pose model_complexity=1')
        for k, f in enumerate(frames):
            js = p.step(f.color, f.depth_m, f.intrinsics, new_video=k == 0)
            assert p.last_cpu_s > 0.0
            for side in ('shoulder', 'hip'):
                mine = [js.index(f'{s}_{side}') for s in ('left', 'right')]
                truth = [f.truth.index(ground_truth_name(f'{s}_{side}'))
                         for s in ('left', 'right')]
                d = np.linalg.norm(js.uv[mine] - f.truth.uv[truth], axis=1)
                swapped = np.linalg.norm(js.uv[mine] - f.truth.uv[truth[::-1]], axis=1)
                pixel.extend(d)
                own_side.append(d.sum() < swapped.sum())
                metric.extend(np.linalg.norm(js.xyz[mine] - f.truth.xyz[truth], axis=1))
    assert all(own_side)  # MediaPipe's left is the person's left, as ours
    assert np.median(pixel) < 10.0, pixel  # px, a person about 200 px tall
    assert np.median(metric) < 0.15, metric  # m: the joint centre lies behind the surface
