"""The peer's joints lifted to 3-D as fairly as ours: a per-joint depth offset fitted on training
renders (`pose4d eval --fit-peer-depth`, `--peer-depth`).

The peer (`pose4d_ros.peer`) lifts each joint at the surface the camera sees (`robust_depth`,
the median of a 7 x 7 window); a joint's centre lies behind that surface. Our detector adds a
learned depth offset per part (`training.dpm.train.calibrate`: the median of joint depth less
surface depth over the parts it places right on its training frames). `fit_depth_offsets`
learns the same for the peer: for each joint, the median of (true depth - lifted depth) over the
frames of a labelled set where the peer places the joint right in the image (within PCK@0.1 of
its label) and has a depth; `offset_row` moves each 3-D joint along its ray by its offset. The
offsets are fitted on training renders (subjects s01-s06), never on a set that is reported, and
the `mediapipe_fit` row of `pose4d eval` is the raw row with them.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from pose4d_ros.core.files import write_json
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import joint_arrays
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.evaluation.pipeline import Row

# A joint is placed right (and its depth used for the fit) within this share of the labelled
# person's box (the PCK@0.1 rule)
FIT_ALPHA = 0.1
# Fewer usable frames than this for a joint: no offset (0) for it
MIN_SAMPLES = 20


def fit_depth_offsets(row: Row, frames: Sequence[Frame]) -> dict[str, dict[str, float]]:
    """Each joint's depth offset (metres, added to the lifted depth) fitted on labelled frames.

    Returns
    -------
    {joint: {'offset_m': median of true - lifted depth, 'n': frames used}} for every joint the
    row predicts; 'offset_m' 0 where fewer than `MIN_SAMPLES` frames could be used.
    """
    if not row.preds:
        raise ValueError('no predictions to fit the depth offsets on')
    names = tuple(row.preds[0].names)
    sizes = [(f.color.shape[1], f.color.shape[0]) for f in frames]
    a = joint_arrays(row.preds, [f.truth for f in frames], names, image_sizes=sizes)
    if a['pred_xyz'] is None:
        raise ValueError('the frames have no 3-D ground truth or the row no 3-D joints')
    gt, vis = a['gt'], a['visible'].astype(bool)
    box = np.full(len(frames), np.nan)
    for i in range(len(frames)):
        pts = gt[i][vis[i]]
        if len(pts):
            box[i] = float(np.max(pts.max(axis=0) - pts.min(axis=0)))
    err = np.linalg.norm(a['pred'] - gt, axis=2)
    dz = a['gt_xyz'][:, :, 2] - a['pred_xyz'][:, :, 2]
    with np.errstate(invalid='ignore'):
        ok = vis & (err <= FIT_ALPHA * box[:, None]) & np.isfinite(dz)
    out = {}
    for j, name in enumerate(names):
        n = int(ok[:, j].sum())
        off = float(np.median(dz[ok[:, j], j])) if n >= MIN_SAMPLES else 0.0
        out[name] = {'offset_m': round(off, 4), 'n': n}
    return out


def offset_joints(joints: JointSet, offsets: Mapping[str, float]) -> JointSet:
    """The joints with each 3-D position moved along its ray to depth z + offset (metres);
    joints without an offset or without 3-D are kept."""
    off = np.array([offsets.get(n, 0.0) for n in joints.names], np.float64)
    xyz = joints.xyz.copy()
    z = xyz[:, 2]
    with np.errstate(invalid='ignore', divide='ignore'):
        factor = np.where(np.isfinite(z) & (z > 0), (z + off) / z, np.nan)
    xyz *= factor[:, None]
    return replace(joints, xyz=xyz)


def offset_row(row: Row, offsets: Mapping[str, float]) -> Row:
    """A row whose every frame's joints are moved by `offset_joints` (same CPU times)."""
    return Row([offset_joints(p, offsets) for p in row.preds], list(row.cpu_ms))


def write_offsets(path: Path, fitted: dict[str, dict[str, float]], *, source: str,
                  peer: str) -> None:
    """The fitted offsets as JSON, with the set and the peer they were fitted on."""
    write_json(path, {'source': source, 'peer': peer, 'fit_alpha': FIT_ALPHA,
                      'joints': fitted}, indent=1)


def read_offsets(path: Path) -> dict[str, float]:
    """{joint: offset metres} from a file of `write_offsets`; ValueError naming the file."""
    try:
        data = json.loads(Path(path).read_text())
        return {str(k): float(v['offset_m']) for k, v in data['joints'].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise ValueError(f'{path}: not a peer depth-offset file ({type(e).__name__}: {e})'
                         ) from None
