"""Reader for LSPET (Leeds Sports Pose Extended): real RGB people with 14 joint labels.

Johnson & Everingham, "Learning effective human pose estimation from inaccurate annotation",
CVPR 2011. Layout: `images/im%05d.jpg` (numbered from 1) and `joints.mat` holding `joints`,
(14, 3, N): x, y in pixels and a flag that is 1 where the joint is labelled (visible). Joints
whose flag is 0 carry no location (zeros or negative numbers), so they are returned as NaN.
Labels are person-centric (left = the person's left), the project's convention, so nothing is
mirrored here. The 'head top' label becomes the skeleton's 'head'.

Suggested split (DATA.md): images 1-2500 train, 2501-3000 test.
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.joints import JointSet
from pose4d_ros.datasets.frame import Frame

# joints.mat order, in skeleton names (head top -> 'head').
LSPET_JOINTS: tuple[str, ...] = (
    'right_ankle', 'right_knee', 'right_hip', 'left_hip', 'left_knee', 'left_ankle',
    'right_wrist', 'right_elbow', 'right_shoulder', 'left_shoulder', 'left_elbow', 'left_wrist',
    'neck', 'head',
)


@lru_cache(maxsize=4)
def _load(path: str, mtime: float) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    import scipy.io
    from scipy.io.matlab import MatReadError

    try:
        mat = scipy.io.loadmat(path, variable_names=['joints'])
    except (OSError, ValueError, TypeError, NotImplementedError, MatReadError) as exc:
        raise ValueError(f'{path}: cannot read as a MATLAB file: {exc}') from exc
    if 'joints' not in mat:
        raise ValueError(f"{path}: no variable 'joints'")
    j = np.asarray(mat['joints'], dtype=np.float64)
    if j.ndim != 3 or j.shape[:2] != (14, 3):
        raise ValueError(f"{path}: 'joints' must be (14, 3, N), got {j.shape}")
    uv = np.transpose(j[:, :2, :], (2, 0, 1)).copy()  # (N, 14, 2)
    vis = np.transpose(j[:, 2, :], (1, 0)) > 0.5
    uv[~vis] = np.nan
    uv.setflags(write=False)
    vis.setflags(write=False)
    return uv, vis


def read_joints(root: str | Path) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """All labels of `root/joints.mat`.

    Returns
    -------
    uv : (N, 14, 2) float64 pixels, `LSPET_JOINTS` order, NaN where not labelled; row i is
        image i + 1. Read-only.
    visible : (N, 14) bool, labelled. Read-only.
    """
    path = Path(root) / 'joints.mat'
    if not path.is_file():
        raise OSError(f'{path}: no such file')
    return _load(str(path), path.stat().st_mtime)


def image_path(root: str | Path, index: int) -> Path:
    """`root/images/im%05d.jpg` of image `index` (from 1)."""
    return Path(root) / 'images' / f'im{index:05d}.jpg'


def read_image(root: str | Path, index: int) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 RGB image number `index` (from 1)."""
    path = image_path(root, index)
    im = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if im is None:
        raise OSError(f'{path}: missing or not an image')
    return cv2.cvtColor(im, cv2.COLOR_BGR2RGB)


def read_frames(root: str | Path, first: int, last: int) -> Iterator[Frame]:
    """Images `first` .. `last` (inclusive, from 1): colour, no depth, the 14 joints' labels as
    ground truth (confidence 1 where labelled); stamps one second apart."""
    uv, vis = read_joints(root)
    if not 1 <= first <= last <= len(uv):
        raise ValueError(f'{Path(root) / "joints.mat"}: range {first}-{last} outside 1-{len(uv)}')
    for i in range(first, last + 1):
        truth = JointSet(LSPET_JOINTS, uv[i - 1], confidence=vis[i - 1])
        yield Frame(i * 1_000_000_000, read_image(root, i), None, None, truth,
                    key=str(image_path(root, i)))
