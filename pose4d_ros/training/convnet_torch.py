"""The PyTorch twin of `core.convnet`: the photograph joint network built, trained and exported
for `core.convnet` (numpy, batch normalisation folded). Training only: it needs PyTorch, which
`make train-env` installs in `.venv-train` (our Python dependencies, PyTorch's CPU build from
`requirements/convnet.txt`, pose4d_ros, no ROS).

The network is trained for a fixed budget (AdamW, cosine learning rate, batches of 32) of wall
time or of the process's CPU time (`time.process_time`, every thread: a budget that does not
depend on other processes sharing the machine; the cosine follows whichever clock), each
photograph turned (within 40 degrees, 1 in 5 any way up), scaled (0.78-1.28), shifted (a
tenth of its size), mirrored with left and right swapped, and its colours jittered; a joint's
loss is the cross-entropy of its softmax over the cells against a Gaussian of one cell around
the label, counted only where the joint is labelled.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pose4d_ros.core.convnet import (
    cell_targets,
    crop_transform,
    layer_names,
    normalise,
    warp,
)
from pose4d_ros.core.foreground import apply_mask
from pose4d_ros.core.skeleton import ground_truth_name
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.util.progress import log

INSTALL = '`make train-env`, then .venv-train/bin/pose4d train-convnet ...'


def import_torch() -> Any:
    """PyTorch, its OpenMP threads set to sleep while they wait (`OMP_WAIT_POLICY=PASSIVE`
    unless set): under a CPU-time budget on a shared machine a spinning thread, waiting for
    one the system has descheduled or for the photographs' augmentation, spends the budget
    without training (measured: 29 % more steps in a CPU minute with 5 other processes on
    the 2 cores). It only takes effect when PyTorch is first imported."""
    os.environ.setdefault('OMP_WAIT_POLICY', 'PASSIVE')
    try:
        import torch
    except ModuleNotFoundError as exc:
        raise ValueError(f'train-convnet needs PyTorch, which is not installed: {INSTALL}') \
            from exc
    return torch


def network(torch: Any, width: int, joints: int) -> Any:
    """The PyTorch twin of `core.convnet.ConvNet.forward` (same layer names)."""
    nn, F = torch.nn, torch.nn.functional

    class Block(nn.Module):
        def __init__(self, cin: int, cout: int, stride: int) -> None:
            super().__init__()
            self.c1 = nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False),
                                    nn.BatchNorm2d(cout))
            self.c2 = nn.Sequential(nn.Conv2d(cout, cout, 3, 1, 1, bias=False),
                                    nn.BatchNorm2d(cout))
            self.skip = None if cin == cout and stride == 1 else nn.Sequential(
                nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

        def forward(self, x: Any) -> Any:
            y = self.c2(F.relu(self.c1(x)))
            return F.relu(y + (x if self.skip is None else self.skip(x)))

    class Net(nn.Module):
        def __init__(self, w: int) -> None:
            super().__init__()
            self.stem = nn.Sequential(nn.Conv2d(3, w, 3, 2, 1, bias=False), nn.BatchNorm2d(w))
            self.s2 = nn.Sequential(Block(w, 2 * w, 2), Block(2 * w, 2 * w, 1))
            self.s3 = nn.Sequential(Block(2 * w, 4 * w, 2), Block(4 * w, 4 * w, 1))
            self.s4 = nn.Sequential(Block(4 * w, 6 * w, 2), Block(6 * w, 6 * w, 1),
                                    Block(6 * w, 6 * w, 1))
            self.l3 = nn.Conv2d(4 * w, 6 * w, 1)
            self.u3 = Block(6 * w, 4 * w, 1)
            self.l2 = nn.Conv2d(2 * w, 4 * w, 1)
            self.u2 = Block(4 * w, 2 * w, 1)
            self.head = nn.Conv2d(2 * w, joints, 1)

        def forward(self, x: Any) -> Any:
            a = self.s2(F.relu(self.stem(x)))
            b = self.s3(a)
            c = self.s4(b)
            y = self.u3(F.interpolate(c, scale_factor=2, mode='nearest') + self.l3(b))
            y = self.u2(F.interpolate(y, scale_factor=2, mode='nearest') + self.l2(a))
            return self.head(y)

    return Net(width)


def import_weights(torch: Any, net: Any, weights: dict[str, tuple[np.ndarray, np.ndarray]]
                   ) -> None:
    """Load `core.convnet` weights (batch normalisation folded) into the PyTorch network, each
    batch normalisation an identity around the folded bias (mean 0, variance 1 - eps, scale 1):
    the same function, for fine-tuning (`train`'s `init`, statistics frozen); `export_weights`
    gives the weights back."""
    modules = dict(net.named_modules())
    with torch.no_grad():
        for name in layer_names():
            w, b = weights[name]
            m = modules[name]
            conv, bn = (m[0], m[1]) if hasattr(m, '__getitem__') else (m, None)
            if tuple(conv.weight.shape) != (w.shape[3], w.shape[2], w.shape[0], w.shape[1]):
                raise ValueError(f'layer {name}: weights {w.shape} do not fit the network '
                                 f'({tuple(conv.weight.shape)}): another --width?')
            conv.weight.copy_(torch.from_numpy(np.ascontiguousarray(w.transpose(3, 2, 0, 1))))
            if bn is None:
                conv.bias.copy_(torch.from_numpy(b))
                continue
            bn.weight.fill_(1.0)
            bn.bias.copy_(torch.from_numpy(b))
            bn.running_mean.zero_()
            bn.running_var.fill_(1.0 - bn.eps)


def export_weights(net: Any) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """`core.convnet` weights of the PyTorch network: (k, k, C_in, C_out) and (C_out,) per
    layer, each batch normalisation folded into the convolution before it."""
    modules = dict(net.named_modules())
    out = {}
    for name in layer_names():
        m = modules[name]
        conv, bn = (m[0], m[1]) if hasattr(m, '__getitem__') else (m, None)
        w = conv.weight.detach().double().numpy()
        b = conv.bias.detach().double().numpy() if conv.bias is not None else \
            np.zeros(w.shape[0])
        if bn is not None:
            s = bn.weight.detach().double().numpy() / np.sqrt(
                bn.running_var.detach().double().numpy() + bn.eps)
            w = w * s[:, None, None, None]
            b = (b - bn.running_mean.detach().double().numpy()) * s + \
                bn.bias.detach().double().numpy()
        out[name] = (w.transpose(2, 3, 1, 0).astype(np.float32).copy(), b.astype(np.float32))
    return out


def render_crops(frames: Iterable[Frame], names: Sequence[str], *, margin: float = 0.12,
                 backgrounds: Sequence[bool] = (False,)
                 ) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Training photographs from rendered RGB-D frames, the person as the detector's crop shows
    them (`core.dpm.net_unary`): the colour blanked outside the person's ground-truth mask
    (as the foreground stage blanks it), cut to the mask's box plus `margin` of its height on
    every side; each joint of `names` at its pixel in the crop (the truth's `*_hand` and
    `*_foot` for `*_wrist` and `*_ankle`), labelled where the truth has it inside the crop.
    Each frame is cut once per value of `backgrounds` (False: blanked; True: as rendered, the
    room kept), read once; the crops of the first value come first. Frames without a mask, an
    empty one or several people are left out. Returns the crops, (N, J, 2) pixels and (N, J)
    labelled flags."""
    images: dict[bool, list[np.ndarray]] = {bg: [] for bg in backgrounds}
    uvs, labelled = [], []
    for f in frames:
        if f.mask is None or f.truth is None or f.people or not f.mask.any():
            continue
        rows = np.flatnonzero(f.mask.any(axis=1))
        cols = np.flatnonzero(f.mask.any(axis=0))
        pad = margin * (rows[-1] + 1 - rows[0])
        h, w = f.mask.shape
        x0, y0 = max(int(cols[0] - pad), 0), max(int(rows[0] - pad), 0)
        x1, y1 = min(int(np.ceil(cols[-1] + 1 + pad)), w), min(int(np.ceil(rows[-1] + 1 + pad)), h)
        for bg in backgrounds:
            color = f.color if bg else \
                apply_mask(f.color, np.zeros(f.mask.shape, np.float32), f.mask)[0]
            images[bg].append(np.ascontiguousarray(color[y0:y1, x0:x1]))
        truth = f.truth
        index = {n: i for i, n in enumerate(truth.names)}
        uv = np.full((len(names), 2), np.nan)
        vis = np.zeros(len(names), bool)
        for j, name in enumerate(names):
            i = index.get(ground_truth_name(name), index.get(name))
            if i is None or not truth.confidence[i] > 0:
                continue
            u, v = truth.uv[i, 0] - x0, truth.uv[i, 1] - y0
            if 0 <= u < x1 - x0 and 0 <= v < y1 - y0:
                uv[j], vis[j] = (u, v), True
        uvs.append(uv)
        labelled.append(vis)
    k = len(images)
    return [im for bg in images for im in images[bg]], \
        np.tile(np.array(uvs).reshape(-1, len(names), 2), (k, 1, 1)), \
        np.tile(np.array(labelled, bool).reshape(-1, len(names)), (k, 1))


def _sample(rng: np.random.Generator, image: np.ndarray, uv: np.ndarray, vis: np.ndarray,
            mirror: list[int], input_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One augmented photograph: input (S, S, 3) float 0-255, its joints' input pixels and
    labelled flags (mirrored joints swapped left for right)."""
    h, w = image.shape[:2]
    flip = bool(rng.random() < 0.5)
    rotation = rng.uniform(-40, 40) if rng.random() < 0.8 else rng.uniform(-180, 180)
    m = crop_transform(image.shape, input_px, scale=math.exp(rng.uniform(-0.25, 0.25)),
                       rotation_deg=rotation, mirror=flip,
                       shift_px=tuple(rng.uniform(-0.1, 0.1, 2) * max(h, w)))
    x = warp(image, m, input_px).astype(np.float32)
    x = np.clip(x * rng.uniform(0.7, 1.3, 3) + rng.uniform(-20, 20), 0, 255)
    p = np.c_[np.nan_to_num(uv), np.ones(len(uv))] @ m.T
    if flip:
        p, vis = p[mirror], vis[mirror]
    return x, p, vis


@dataclass(frozen=True)
class Trained:
    """A trained network (`net`, in eval mode) and how its training went."""

    net: Any
    steps: int
    epochs: int
    losses: list[float]


class Budget:
    """Where training stands in its budget: `minutes` of wall time from now, or `cpu_minutes`
    of the process's CPU time (`time.process_time`, all threads) counted from `cpu_since` (a
    `time.process_time()` value; 0, the process's start, by default: what was spent before
    now, e.g. reading the photographs, counts). `done()` is the fraction of what remained at
    construction that has been spent since (1 or more: the budget is spent)."""

    def __init__(self, *, minutes: float | None = None, cpu_minutes: float | None = None,
                 cpu_since: float = 0.0) -> None:
        if (minutes is None) == (cpu_minutes is None):
            raise ValueError('a training budget of either wall minutes or CPU minutes')
        budget = cpu_minutes if minutes is None else minutes
        if budget is None or budget <= 0:
            raise ValueError(f'the training budget must be > 0 minutes, got {budget}')
        self.clock = time.time if minutes is not None else time.process_time
        self.start = self.clock()
        self.end = self.start + 60.0 * (minutes if minutes is not None else
                                        cpu_minutes - (self.start - cpu_since) / 60.0)
        self.text = f'{minutes} min' if minutes is not None else f'{cpu_minutes} CPU min'

    def done(self) -> float:
        if self.end <= self.start:
            return 1.0
        return (self.clock() - self.start) / (self.end - self.start)


PRECISIONS = ('fp32', 'bf16')


def train(torch: Any, images: Sequence[np.ndarray], uv: np.ndarray, vis: np.ndarray,
          mirror: Sequence[int], *, budget: Budget, input_px: int, width: int,
          rng: np.random.Generator, precision: str = 'fp32', lr: float = 2e-3,
          init: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> Trained:
    """The network trained on `images` (their joints `uv`, visible where `vis`; `mirror` swaps
    left and right) until `budget` is spent: the loop of the module docstring, the learning
    rate falling from `lr` along a cosine. `precision` 'bf16' runs the network's forward pass
    under CPU autocast to bfloat16 (the weights, the optimiser and the loss stay float32): on
    a CPU with AMX or AVX512-BF16 about 3x the steps in the same time. `init`: a trained
    network's weights (`core.convnet.ConvNet.weights`) to fine-tune, its batch
    normalisations' statistics frozen (`import_weights`)."""
    if precision not in PRECISIONS:
        raise ValueError(f'precision must be one of {PRECISIONS}, got {precision!r}')
    cells = input_px // 4
    # channels-last tensors: the same arithmetic, 13 % less CPU a step (oneDNN's layout)
    net = network(torch, width, len(mirror))
    norms = []
    if init is not None:
        import_weights(torch, net, init)
        norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    net = net.to(memory_format=torch.channels_last)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    log(f'{len(images)} photographs, {sum(p.numel() for p in net.parameters()) / 1e6:.2f} M '
        f'weights, {budget.text}')
    t0, c0 = time.time(), time.process_time()
    steps = epochs = 0
    losses: list[float] = []
    batch = min(32, len(images))  # a set smaller than a batch trains in batches of all of it
    if batch < 1:
        raise ValueError('train-convnet: no photographs to train on')
    while budget.done() < 1:
        order = rng.permutation(len(images))
        for k in range(0, len(order) - batch + 1, batch):
            done = budget.done()
            if done >= 1:
                break
            for group in opt.param_groups:
                group['lr'] = lr * 0.5 * (1 + math.cos(math.pi * done))
            net.train()
            for m in norms:  # fine-tuning: the statistics as imported
                m.eval()
            xs, ts, ws = [], [], []
            for i in order[k:k + batch]:
                x, p, v = _sample(rng, images[i], uv[i], vis[i], mirror, input_px)
                t, wt = cell_targets(p, v, cells)
                xs.append(x)
                ts.append(t)
                ws.append(wt)
            x = torch.from_numpy(normalise(np.stack(xs))).permute(0, 3, 1, 2)  # channels last
            t = torch.from_numpy(np.stack(ts)).flatten(2)
            wt = torch.from_numpy(np.stack(ws))
            with torch.autocast('cpu', dtype=torch.bfloat16, enabled=precision == 'bf16'):
                out = net(x)
            logp = torch.nn.functional.log_softmax(out.float().flatten(2), -1)
            loss = (-(t * logp).sum(-1) * wt).sum() / wt.sum().clamp(min=1)
            opt.zero_grad()
            loss.backward()
            opt.step()
            steps += 1
            losses.append(loss.item())
            if steps % 200 == 0:
                log(f'{time.time() - t0:5.0f} s, {time.process_time() - c0:5.0f} CPU s, '
                    f'{100 * done:4.1f} % of the budget, step {steps}, '
                    f'loss {np.mean(losses[-200:]):.3f}')
        epochs += 1
    net = net.to(memory_format=torch.contiguous_format)
    net.eval()
    return Trained(net, steps, epochs, losses)
