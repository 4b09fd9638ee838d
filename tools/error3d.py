"""Where the 3-D error of the published skeleton comes from: depth or the image plane.

    .venv/bin/python tools/error3d.py data/synth/test [--model rgbd_14]

Runs the pipeline (`rgbd_kf_ik`, as `pose4d eval` does) over a labelled CAD-60 set or bag and
prints per joint group: the median 3-D error and the share within 10 cm (as `pose4d eval`),
the median depth error |dz| and the share of joints whose depth is over 8 cm off, the median
error across the image plane (x, y) and the share over 8 cm, the median pixel error, and the
median signed depth error (negative: in front of the joint).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the source tree

from pose4d_ros.cli._dpm import load_frames  # noqa: E402
from pose4d_ros.cli._pipeline_eval import pipeline_rows  # noqa: E402
from pose4d_ros.core.dpm.model import load_model  # noqa: E402
from pose4d_ros.core.dpm.threads import set_blas_threads  # noqa: E402
from pose4d_ros.core.skeleton import SKELETON_14  # noqa: E402
from pose4d_ros.models import model_path  # noqa: E402


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('source', help='labelled CAD-60 directory or bag')
    ap.add_argument('--model', default='rgbd_14')
    args = ap.parse_args(argv)
    set_blas_threads(1)
    frames = load_frames([args.source])
    preds = pipeline_rows(frames, load_model(model_path(args.model)))['rgbd_kf_ik'].preds
    groups: dict[str, list] = {}
    for f, p in zip(frames, preds, strict=True):
        tuv, txyz, labelled = f.truth.labelled(SKELETON_14)
        for j, name in enumerate(SKELETON_14):
            if not labelled[j]:
                continue
            k = p.names.index(name)
            e = p.xyz[k] - txyz[j]
            groups.setdefault(name.removeprefix('left_').removeprefix('right_'), []).append(
                (np.linalg.norm(e), abs(e[2]), np.hypot(e[0], e[1]),
                 np.hypot(*(p.uv[k] - tuv[j])), e[2]))
    print(f"{'group':9s} {'3-D mm':>7s} {'<10 cm':>7s} {'|dz| mm':>8s} {'dz>8cm':>7s} "
          f"{'xy mm':>6s} {'xy>8cm':>7s} {'px':>5s} {'dz mm':>6s}")
    for g, rows in groups.items():
        a = np.array(rows)
        a[~np.isfinite(a[:, 0]), :3] = np.inf  # no 3-D position: infinitely far, as eval
        print(f'{g:9s} {1e3 * np.median(a[:, 0]):7.1f} {100 * np.mean(a[:, 0] < 0.1):7.1f} '
              f'{1e3 * np.median(a[:, 1]):8.1f} {100 * np.mean(a[:, 1] > 0.08):7.1f} '
              f'{1e3 * np.median(a[:, 2]):6.1f} {100 * np.mean(a[:, 2] > 0.08):7.1f} '
              f'{np.nanmedian(a[:, 3]):5.1f} {1e3 * np.nanmedian(a[:, 4]):6.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
