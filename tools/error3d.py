"""Where the 3-D error of the published skeleton comes from: depth or the image plane.

    .venv/bin/python tools/error3d.py data/synth/test [--model rgbd_14] [--ceiling]

Runs the pipeline (`rgbd_kf_ik`, as `pose4d eval` does) over a labelled CAD-60 set or bag and
prints per joint group: the median 3-D error and the share within 10 cm (as `pose4d eval`),
the median depth error |dz| and the share of joints whose depth is over 8 cm off, the share of
those lying in front of the joint, the median error across the image plane (x, y) and the share
over 8 cm, the median pixel error, the median signed depth error (negative: in front of the
joint), and the share within 10 cm were each joint's depth exact (the true depth at the
published pixel).

`--ceiling` asks what a better image position would buy instead: the detector alone on each
frame (the set's person mask, as the calibration runs it), each part moved onto its labelled
pixel when it lies within R pixels of it (a perfect refinement of reach R), then lifted by the
model's own look-up; the share within 10 cm per group for each R (inf: every part at its label,
which leaves only the look-up's error).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from pose4d_ros.core.camera import backproject
from pose4d_ros.core.dpm.infer import Detector
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.lifting import lift_parts
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.core.threads import set_blas_threads
from pose4d_ros.datasets.sources import load_frames
from pose4d_ros.evaluation.pipeline import pipeline_rows
from pose4d_ros.models import model_path

REACH_PX = (0, 5, 7, 9, 12, np.inf)


def group(name: str) -> str:
    return name.removeprefix('left_').removeprefix('right_')


def within(err: list[float]) -> float:
    return 100 * float(np.mean(np.nan_to_num(np.asarray(err), nan=np.inf) < 0.1))


def sources(frames: list, model) -> int:
    preds = pipeline_rows(frames, model)['rgbd_kf_ik'].preds
    groups: dict[str, list] = {}
    for f, p in zip(frames, preds, strict=True):
        tuv, txyz, labelled = f.truth.labelled(SKELETON_14)
        exact = backproject(p.uv, np.ones(len(p.uv)), f.intrinsics)
        for j, name in enumerate(SKELETON_14):
            if not labelled[j]:
                continue
            k = p.names.index(name)
            e = p.xyz[k] - txyz[j]
            groups.setdefault(group(name), []).append(
                (np.linalg.norm(e), abs(e[2]), np.hypot(e[0], e[1]),
                 np.hypot(*(p.uv[k] - tuv[j])), e[2],
                 np.linalg.norm(exact[k] * txyz[j, 2] - txyz[j])))
    print(f"{'group':9s} {'3-D mm':>7s} {'<10 cm':>7s} {'|dz| mm':>8s} {'dz>8cm':>7s} "
          f"{'in front':>8s} {'xy mm':>6s} {'xy>8cm':>7s} {'px':>5s} {'dz mm':>6s} "
          f"{'<10 cm, exact z':>15s}")
    for g, rows in groups.items():
        a = np.array(rows)
        a[~np.isfinite(a[:, 0]), :3] = np.inf  # no 3-D position: infinitely far, as eval
        off = a[:, 1] > 0.08
        front = 100 * np.mean(a[off, 4] < 0) if off.any() else np.nan
        print(f'{g:9s} {1e3 * np.median(a[:, 0]):7.1f} {100 * np.mean(a[:, 0] < 0.1):7.1f} '
              f'{1e3 * np.median(a[:, 1]):8.1f} {100 * np.mean(off):7.1f} {front:8.1f} '
              f'{1e3 * np.median(a[:, 2]):6.1f} {100 * np.mean(a[:, 2] > 0.08):7.1f} '
              f'{np.nanmedian(a[:, 3]):5.1f} {1e3 * np.nanmedian(a[:, 4]):6.1f} '
              f'{within(a[:, 5]):15.1f}')
    return 0


def ceiling(frames: list, model) -> int:
    det = Detector(model)
    errs: dict[str, dict[float, list]] = {}
    for f in frames:
        uv, xyz, vis = f.truth.labelled(model.part_names)
        poses = det.detect(f.color, f.depth_m, mask=f.mask, intrinsics=f.intrinsics)
        if not poses:
            continue
        near = np.hypot(*(poses[0].uv - uv).T)
        for reach in REACH_PX:
            moved = np.where((vis & (near <= reach))[:, None], uv, poses[0].uv)
            got = backproject(moved, lift_parts(model, f.depth_m, moved, f.intrinsics, f.mask),
                              f.intrinsics)
            for j in np.flatnonzero(vis & np.isfinite(xyz).all(axis=1)):
                errs.setdefault(group(model.part_names[j]), {}).setdefault(reach, []).append(
                    np.linalg.norm(got[j] - xyz[j]))
    print('share within 10 cm (%), parts moved onto their labels from within R px')
    print(f"{'group':9s}" + ''.join(f'{"R=" + str(r):>8s}' for r in REACH_PX))
    total = np.zeros(len(REACH_PX))
    for g, by_reach in errs.items():
        w = np.array([within(by_reach[r]) for r in REACH_PX])
        total += w * (g != 'neck')
        print(f'{g:9s}' + ''.join(f'{x:8.1f}' for x in w))
    print(f"{'average7':9s}" + ''.join(f'{x:8.1f}' for x in total / 7))
    return 0


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('source', help='labelled CAD-60 directory or bag')
    ap.add_argument('--model', default='rgbd_14')
    ap.add_argument('--ceiling', action='store_true',
                    help='what a perfect image position within R px would buy')
    args = ap.parse_args(argv)
    set_blas_threads(1)
    frames = load_frames([args.source])
    model = load_model(model_path(args.model))
    return (ceiling if args.ceiling else sources)(frames, model)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
