"""LSPET reader (datasets.lspet): the real joints.mat when present, and hand-made files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.datasets import lspet
from pose4d_ros.datasets.sources import open_source, parse_range, parse_ranges, source_kind

LSPET = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'lspet'


def write_lspet(root: Path, joints: np.ndarray, n_images: int) -> None:
    (root / 'images').mkdir(parents=True)
    scipy.io.savemat(root / 'joints.mat', {'joints': joints})
    rng = np.random.default_rng(0)
    for i in range(1, n_images + 1):
        im = rng.integers(0, 256, (40 + i, 30, 3)).astype(np.uint8)
        cv2.imwrite(str(root / 'images' / f'im{i:05d}.jpg'), im)


def test_names_are_skeleton_names() -> None:
    assert len(lspet.LSPET_JOINTS) == 14
    assert lspet.LSPET_JOINTS[13] == 'head' and lspet.LSPET_JOINTS[12] == 'neck'
    assert lspet.LSPET_JOINTS[0] == 'right_ankle' and lspet.LSPET_JOINTS[11] == 'left_wrist'


def test_hand_made_file_reads_back(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    j = np.zeros((14, 3, 3))
    j[:, :2] = rng.uniform(5, 25, (14, 2, 3))
    j[:, 2] = 1
    j[4, :, 1] = (0.0, -12.0, 0.0)                   # an unlabelled joint of image 2
    write_lspet(tmp_path, j, 3)
    uv, vis = lspet.read_joints(tmp_path)
    assert uv.shape == (3, 14, 2) and vis.shape == (3, 14)
    assert_allclose(uv[0], j[:, :2, 0])
    assert not vis[1, 4] and np.isnan(uv[1, 4]).all()
    assert vis.sum() == 3 * 14 - 1
    frames = list(lspet.read_frames(tmp_path, 2, 3))
    assert [f.color.shape for f in frames] == [(42, 30, 3), (43, 30, 3)]
    assert frames[0].depth_m is None and frames[0].truth.names == lspet.LSPET_JOINTS
    uv, _, labelled = frames[0].truth.labelled(lspet.LSPET_JOINTS)
    assert_array_equal(labelled, vis[1])
    assert_allclose(uv[labelled], j[:, :2, 1][vis[1]])
    assert source_kind(tmp_path) == 'lspet'
    assert len(list(open_source(tmp_path, frame_range=(1, 3)))) == 3


def test_bad_files_and_ranges(tmp_path: Path) -> None:
    with pytest.raises(OSError, match='joints.mat'):
        lspet.read_joints(tmp_path)
    (tmp_path / 'joints.mat').write_bytes(b'garbage')
    with pytest.raises(ValueError, match='joints.mat'):
        lspet.read_joints(tmp_path)
    other = tmp_path / 'other'
    write_lspet(other, np.zeros((13, 3, 2)), 1)
    with pytest.raises(ValueError, match=r"\(14, 3, N\)"):
        lspet.read_joints(other)
    good = tmp_path / 'good'
    write_lspet(good, np.ones((14, 3, 2)), 2)
    with pytest.raises(ValueError, match='range 2-5 outside 1-2'):
        list(lspet.read_frames(good, 2, 5))
    with pytest.raises(ValueError, match='needs --range'):
        open_source(good)
    (good / 'images' / 'im00002.jpg').unlink()
    with pytest.raises(OSError, match='im00002.jpg'):
        list(lspet.read_frames(good, 1, 2))
    with pytest.raises(ValueError, match='A-B'):
        parse_range('12')
    assert parse_range('2501-3000') == (2501, 3000)
    assert parse_ranges('1-2500,3001-8500') == [(1, 2500), (3001, 8500)]
    assert parse_ranges('5-9') == [(5, 9)]
    with pytest.raises(ValueError, match='without overlap'):
        parse_ranges('1-2500,2500-3000')
    with pytest.raises(ValueError, match='A-B'):
        parse_ranges('1-2500,')


@pytest.mark.shared_data
def test_real_lspet_file() -> None:
    if not (LSPET / 'joints.mat').is_file():
        pytest.skip(f'needs the shared LSPET data at {LSPET} (absent in this checkout)')
    uv, vis = lspet.read_joints(LSPET)
    assert uv.shape == (10000, 14, 2)
    # image 1 (README layout): right ankle unlabelled, the others labelled
    assert not vis[0, 0] and vis[0, 1:].all()
    assert_allclose(uv[0, 13], (116.56859752, 53.42206246), atol=1e-6)    # head top
    # unlabelled joints carry no location; labelled ones lie near their image
    assert np.isnan(uv[~vis]).all() and np.isfinite(uv[vis]).all()
    (s,) = list(lspet.read_frames(LSPET, 1, 1))
    h, w = s.color.shape[:2]
    assert s.color.dtype == np.uint8 and (h, w) == (105, 157)
    inside = (uv[:3000, :, 0] > -20) & (uv[:3000, :, 1] > -20)
    assert_array_equal(inside[vis[:3000]], True)
