"""The PyTorch twin of the photograph network computes what `core.convnet` does: a random
network (batch normalisation with statistics other than the identity) through both, largest
difference printed; exit status 1 if it is over `TOLERANCE`. Run by `test_convnet.py` in this
Python when it has PyTorch, else with the training venv's (`make train-env`, `.venv-train`)."""

from __future__ import annotations

import sys

import numpy as np

from pose4d_ros.core import convnet as cn
from pose4d_ros.core.convnet import ConvNet

TOLERANCE = 1e-4


def twin_difference() -> float:
    """The largest absolute difference between the twins' outputs on a random photograph."""
    import torch

    from pose4d_ros.training.convnet_torch import export_weights, network

    torch.manual_seed(0)
    net = network(torch, 4, 14)
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm2d):  # statistics other than the identity
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
            m.weight.data.uniform_(0.5, 1.5)
            m.bias.data.uniform_(-0.2, 0.2)
    net.eval()
    x = cn.normalise(np.random.default_rng(0).integers(0, 256, (64, 64, 3)))
    with torch.no_grad():
        expected = net(torch.from_numpy(x.transpose(2, 0, 1)[None].copy()))[0].numpy()
    names = tuple(f'j{i}' for i in range(14))
    mirror = tuple(range(14))
    ours = ConvNet(names, mirror, 64, export_weights(net)).forward(x)
    if ours.shape != expected.shape:
        raise ValueError(f'onnxruntime output {ours.shape}, PyTorch output {expected.shape}')
    return float(np.abs(ours - expected).max())


if __name__ == '__main__':
    diff = twin_difference()
    print(f'largest difference between the PyTorch and onnxruntime networks: {diff:.2e} '
          f'(tolerance {TOLERANCE:.0e})')
    sys.exit(0 if diff <= TOLERANCE else 1)
