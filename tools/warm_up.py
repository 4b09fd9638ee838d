"""Compile pose4d_ros's numba kernels once after installing, so nodes start fast.

numba caches compiled kernels next to the installed modules (`cache=True`); a fresh install has
none, and the first node to run a kernel would spend seconds compiling it. `make setup` runs
this after each install. Warms every shipped part model (the photograph network, `core.convnet`,
is numpy and has no kernels to compile).
"""

import sys
import time

from pose4d_ros import wire
from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.convnet import is_convnet
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.pipeline import FramePipeline
from pose4d_ros.core.stages import DetectorStage, ForegroundStage
from pose4d_ros.models import model_path, shipped_models


def main() -> int:
    t0 = time.monotonic()
    intr = cad60_intrinsics()
    wire.warm_up()
    ForegroundStage().warm_up(intr)
    part_models = [n for n in shipped_models() if not is_convnet(model_path(n))]
    for name in part_models:
        detector = DetectorStage(load_model(model_path(name)))
        detector.warm_up(intr)  # and the detector node's read-only frames
        FramePipeline(detector).warm_up(intr)
    print(f'compiled the kernels (depth decoders, foreground, {len(part_models)} shipped part '
          f'model(s)) in {time.monotonic() - t0:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
