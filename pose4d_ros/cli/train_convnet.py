"""`pose4d train-convnet`: train the photograph joint network (`core.convnet`) on LSPET.

    pose4d train-convnet LSPET --range 1-2500,3001-8500 --renders data/synth/train ... \
        --precision bf16 --minutes 55 --out lspet_convnet.npz

Needs PyTorch, for training only: `make train-env` makes `.venv-train` (our Python
dependencies, PyTorch's CPU build from `requirements/convnet.txt`, pose4d_ros, no ROS), whose
`pose4d train-convnet` this is. How the network is trained: `training.convnet_torch`. The
weights are written for `core.convnet` (numpy, batch normalisation folded) with the command,
data, seed, budget and times (wall and CPU) in the model's metadata. The budget is either wall
time (`--minutes`) or this process's CPU time over all its threads (`--cpu-minutes`, reading
the photographs included): the second does not depend on other processes sharing the machine.
The file also holds the network's 8-bit twin, calibrated on the training photographs (`pose4d
quantize-convnet`), which the detector runs by default.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from pose4d_ros.core.convnet import (
    ConvNet,
    calibration_batches,
    calibration_photographs,
    load_convnet,
    quantize,
    save_convnet,
)
from pose4d_ros.core.skeleton import mirror_index
from pose4d_ros.datasets import lspet
from pose4d_ros.datasets.sources import open_source, parse_ranges, source_kind
from pose4d_ros.models import model_path
from pose4d_ros.training.convnet_torch import (
    PRECISIONS,
    Budget,
    export_weights,
    import_torch,
    render_crops,
    train,
)
from pose4d_ros.util.machine import command_line, machine
from pose4d_ros.util.progress import log


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'train-convnet', help='train the photograph joint network on LSPET (needs PyTorch)',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('source', metavar='LSPET', help='LSPET root')
    p.add_argument('--range', dest='frame_range', default='1-2500', metavar='A-B[,C-D...]',
                   help='LSPET image numbers (inclusive), several ranges separated by commas')
    p.add_argument('--renders', action='append', default=[], type=Path, metavar='DIR',
                   help='also train on a rendered CAD-60 set (pose4d synth), each frame cut '
                        "to its person as the detector's crop shows them (training."
                        'convnet_torch.render_crops); repeatable')
    p.add_argument('--render-stride', type=int, default=1, metavar='N',
                   help='every N-th frame of each rendered video')
    p.add_argument('--render-background', action='store_true',
                   help='each rendered crop also as rendered, the room around the person '
                        'kept (beside the crop blanked outside the person, as the foreground '
                        'stage blanks it)')
    p.add_argument('--init', type=Path, default=None, metavar='MODEL',
                   help='fine-tune this network (.npz or shipped name) instead of training '
                        'a new one (its batch normalisations frozen)')
    p.add_argument('--lr', type=float, default=2e-3,
                   help='the learning rate at the start (it falls along a cosine)')
    p.add_argument('--out', required=True, type=Path, help='model file to write (.npz)')
    budget = p.add_mutually_exclusive_group()
    budget.add_argument('--minutes', type=float, default=None,
                        help='training budget in wall minutes (26 when no budget is given)')
    budget.add_argument('--cpu-minutes', type=float, default=None,
                        help="training budget in this process's CPU minutes (all threads)")
    p.add_argument('--input-px', type=int, default=128, help='network input size, pixels')
    p.add_argument('--width', type=int, default=32, help='channels of the first stage')
    p.add_argument('--threads', type=int, default=2, help='PyTorch CPU threads')
    p.add_argument('--precision', choices=PRECISIONS, default='fp32',
                   help="the forward pass's arithmetic: bf16 (autocast; weights and optimiser "
                        'float32) trains about 3x faster on a CPU with AMX or AVX512-BF16')
    p.add_argument('--seed', type=int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if source_kind(args.source) != 'lspet':
        raise ValueError(f'{args.source}: train-convnet trains on an LSPET root')
    if args.minutes is None and args.cpu_minutes is None:
        args.minutes = 26.0
    budget_min = args.minutes if args.minutes is not None else args.cpu_minutes
    if budget_min <= 0 or args.input_px % 32 or args.width < 4:
        raise ValueError(f'the budget ({budget_min} min) must be > 0, --input-px '
                         f'{args.input_px} a multiple of 32, --width {args.width} at least 4')
    ranges = parse_ranges(args.frame_range)
    init = None
    if args.init is not None:
        init = load_convnet(model_path(str(args.init)))
        if init.input_px != args.input_px or tuple(init.joint_names) != lspet.LSPET_JOINTS:
            raise ValueError(f'--init {args.init}: a network of {init.input_px} px and joints '
                             f'{init.joint_names}, not --input-px {args.input_px} and LSPET\'s')
    torch = import_torch()
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    all_uv, all_vis = lspet.read_joints(args.source)
    if ranges[-1][1] > len(all_uv):
        raise ValueError(f'--range {args.frame_range} outside 1-{len(all_uv)}')
    numbers = [i for first, last in ranges for i in range(first, last + 1)]
    started = time.time()
    images = [lspet.read_image(args.source, i) for i in numbers]
    rows = np.array(numbers) - 1
    names = lspet.LSPET_JOINTS
    mirror = mirror_index(names)
    uv, vis = all_uv[rows], all_vis[rows]
    rendered = {}
    for root in args.renders:
        if source_kind(root) != 'cad60':
            raise ValueError(f'--renders {root}: not a CAD-60 directory (pose4d synth)')
        crops, r_uv, r_vis = render_crops(
            open_source(root, stride=args.render_stride), names,
            backgrounds=(False, True) if args.render_background else (False,))
        if not crops:
            raise ValueError(f'--renders {root}: no frame with one person and a mask')
        images += crops
        uv, vis = np.concatenate([uv, r_uv]), np.concatenate([vis, r_vis])
        rendered[str(root)] = len(crops)
        log(f'{root}: {len(crops)} rendered frames')
    # wall time from here, as before; the process's CPU time from its start (reading counts)
    budget = Budget(minutes=args.minutes, cpu_minutes=args.cpu_minutes)
    done = train(torch, images, uv, vis, mirror, budget=budget,
                 input_px=args.input_px, width=args.width, rng=rng, precision=args.precision,
                 lr=args.lr, init=None if init is None else init.weights)
    minutes = (time.time() - started) / 60.0
    cpu_minutes = time.process_time() / 60.0
    data = ','.join(f'{a}-{b}' for a, b in ranges)
    metadata = {
        'command': command_line('train-convnet'),
        'data': f'LSPET {data}', 'photographs': len(numbers), 'seed': args.seed,
        **({'renders': rendered} if rendered else {}),
        **({'render_background': True} if args.render_background else {}),
        **({'init': str(args.init), 'init_metadata': init.metadata} if init else {}),
        'lr': args.lr,
        'steps': done.steps, 'epochs': done.epochs,
        'final_loss': round(float(np.mean(done.losses[-200:])), 4) if done.losses else None,
        'budget': budget.text,
        'train_minutes': round(minutes, 1),
        'cpu_minutes': round(cpu_minutes, 1),
        'threads': args.threads, 'precision': args.precision,
        'omp_wait_policy': os.environ.get('OMP_WAIT_POLICY'),
        'torch': str(torch.__version__), 'cpu': str(machine()['cpu']),
    }
    model = ConvNet(names, tuple(mirror), args.input_px, export_weights(done.net), metadata)
    # its 8-bit twin, the detector's default, calibrated on the training photographs
    model = quantize(model, calibration_batches(
        [images[k] for k in calibration_photographs(range(len(numbers)))], args.input_px))
    save_convnet(model, args.out)
    log(f'wrote {args.out}: {done.steps} steps, {done.epochs} epochs, {minutes:.1f} wall min, '
        f'{cpu_minutes:.1f} CPU min')
    return 0
