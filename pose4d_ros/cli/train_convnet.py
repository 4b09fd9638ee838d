"""`pose4d train-convnet`: train the photograph joint network (`core.convnet`) on LSPET.

    pose4d train-convnet LSPET --range 1-2500 --minutes 26 --out lspet_convnet.npz

Needs PyTorch, for training only: `make train-env` makes `.venv-train` (our Python
dependencies, PyTorch's CPU build from `requirements/convnet.txt`, pose4d_ros, no ROS), whose
`pose4d train-convnet` this is. How the network is trained: `training.convnet_torch`. The
weights are written for `core.convnet` (numpy, batch normalisation folded) with the command,
data, seed and time in the model's metadata.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from pose4d_ros.core.convnet import ConvNet, save_convnet
from pose4d_ros.core.dpm.samples import mirror_index
from pose4d_ros.datasets import lspet
from pose4d_ros.datasets.sources import source_kind
from pose4d_ros.training.convnet_torch import export_weights, import_torch, train
from pose4d_ros.util.machine import command_line
from pose4d_ros.util.progress import log


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'train-convnet', help='train the photograph joint network on LSPET (needs PyTorch)',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('source', metavar='LSPET', help='LSPET root')
    p.add_argument('--range', dest='frame_range', default='1-2500', metavar='A-B',
                   help='LSPET image numbers (inclusive)')
    p.add_argument('--out', required=True, type=Path, help='model file to write (.npz)')
    p.add_argument('--minutes', type=float, default=26.0, help='training time budget')
    p.add_argument('--input-px', type=int, default=128, help='network input size, pixels')
    p.add_argument('--width', type=int, default=32, help='channels of the first stage')
    p.add_argument('--threads', type=int, default=2, help='PyTorch CPU threads')
    p.add_argument('--seed', type=int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if source_kind(args.source) != 'lspet':
        raise ValueError(f'{args.source}: train-convnet trains on an LSPET root')
    if args.minutes <= 0 or args.input_px % 32 or args.width < 4:
        raise ValueError(f'--minutes {args.minutes} must be > 0, --input-px {args.input_px} a '
                         f'multiple of 32, --width {args.width} at least 4')
    torch = import_torch()
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    first, last = (int(v) for v in args.frame_range.split('-'))
    all_uv, all_vis = lspet.read_joints(args.source)
    if not 1 <= first <= last <= len(all_uv):
        raise ValueError(f'--range {args.frame_range} outside 1-{len(all_uv)}')
    started = time.time()
    images = [lspet.read_image(args.source, i) for i in range(first, last + 1)]
    names = lspet.LSPET_JOINTS
    mirror = mirror_index(names)
    done = train(torch, images, all_uv[first - 1:last], all_vis[first - 1:last], mirror,
                 minutes=args.minutes, input_px=args.input_px, width=args.width, rng=rng)
    minutes = (time.time() - started) / 60.0
    metadata = {
        'command': command_line('train-convnet'),
        'data': f'LSPET {first}-{last}', 'seed': args.seed, 'steps': done.steps,
        'epochs': done.epochs,
        'final_loss': round(float(np.mean(done.losses[-200:])), 4) if done.losses else None,
        'train_minutes': round(minutes, 1), 'threads': args.threads,
        'torch': str(torch.__version__),
    }
    model = ConvNet(names, tuple(mirror), args.input_px, export_weights(done.net), metadata)
    save_convnet(model, args.out)
    log(f'wrote {args.out}: {done.steps} steps, {done.epochs} epochs, {minutes:.1f} min')
    return 0
