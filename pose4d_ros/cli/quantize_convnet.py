"""`pose4d quantize-convnet`: add the photograph network's 8-bit twin (`core.convnet.quantize`).

    pose4d quantize-convnet pose4d_ros/models/lspet_convnet.npz ../shared/data/lspet \
        --range 1-2500 --renders data/synth/train --out lspet_convnet.npz

The activations' ranges are calibrated on inputs as the detector reads them (`ConvNet.heat_maps`
at scale 1, each with its mirror image): training photographs of LSPET and rendered people cut
as the detector's crop shows them (`training.convnet_torch.render_crops`). Needs no PyTorch.
The network's float weights are kept; the detector node runs the twin with
`detector.colour_net_precision:=int8`, `pose4d eval` with `--net-precision int8`.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

from pose4d_ros.core.convnet import (
    CALIBRATION_PHOTOGRAPHS,
    calibration_batches,
    calibration_photographs,
    load_convnet,
    quantize,
    save_convnet,
)
from pose4d_ros.datasets import lspet
from pose4d_ros.datasets.sources import open_source, parse_ranges, source_kind
from pose4d_ros.models import model_path
from pose4d_ros.training.convnet_torch import render_crops
from pose4d_ros.util.machine import command_line
from pose4d_ros.util.progress import log


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'quantize-convnet', help="add the photograph network's 8-bit twin (int8 inference)",
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('model', help='the network (.npz or shipped name, e.g. lspet_convnet)')
    p.add_argument('source', metavar='LSPET', help='LSPET root (calibration photographs)')
    p.add_argument('--range', dest='frame_range', default='1-2500', metavar='A-B[,C-D...]',
                   help='LSPET image numbers to calibrate on (training photographs)')
    p.add_argument('--photographs', type=int, default=CALIBRATION_PHOTOGRAPHS,
                   help='about as many photographs taken, evenly spread over --range (every '
                   'k-th, as train-convnet takes them)')
    p.add_argument('--renders', action='append', default=[], type=Path, metavar='DIR',
                   help='also calibrate on a rendered CAD-60 set (pose4d synth); repeatable')
    p.add_argument('--render-stride', type=int, default=30, metavar='N',
                   help='every N-th frame of each rendered video')
    p.add_argument('--out', required=True, type=Path, help='model file to write (.npz)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if source_kind(args.source) != 'lspet':
        raise ValueError(f'{args.source}: quantize-convnet calibrates on an LSPET root')
    if args.photographs < 1:
        raise ValueError(f'--photographs must be >= 1, got {args.photographs}')
    started = time.time()
    net = load_convnet(model_path(args.model))
    numbers = [i for first, last in parse_ranges(args.frame_range)
               for i in range(first, last + 1)]
    numbers = calibration_photographs(numbers, args.photographs)
    images = [lspet.read_image(args.source, i) for i in numbers]
    rendered = {}
    for root in args.renders:
        if source_kind(root) != 'cad60':
            raise ValueError(f'--renders {root}: not a CAD-60 directory (pose4d synth)')
        crops, _, _ = render_crops(open_source(root, stride=args.render_stride),
                                   net.joint_names)
        if not crops:
            raise ValueError(f'--renders {root}: no frame with one person and a mask')
        images += crops
        rendered[str(root)] = len(crops)

    out = quantize(net, calibration_batches(images, net.input_px))
    metadata = dict(out.metadata, quantized={
        'command': command_line('quantize-convnet'), 'photographs': len(numbers),
        'data': f'LSPET {args.frame_range}', **({'renders': rendered} if rendered else {}),
        'format': 'ONNX QDQ: weights int8 per channel at 7 bits, activations uint8 (min-max)'})
    save_convnet(replace(out, metadata=metadata), args.out)
    log(f'wrote {args.out}: calibrated on {len(images)} crops in '
        f'{time.time() - started:.0f} s')
    return 0
