"""A stand-in for the MediaPipe worker (no MediaPipe needed): `pose4d_ros/peer/worker.py`'s own
protocol loop with a fake estimator, run by the test's Python.

Landmark i of a frame lies at (width - 1 - i, rgb[0, 0, 0] + 2 i) with visibility 1 on the
first frame of a video (reset) and 0.25 after; a frame whose first pixel has blue 0 has no person.
"""

import importlib.util
import sys

import numpy as np

spec = importlib.util.spec_from_file_location('worker', sys.argv[1])
worker = importlib.util.module_from_spec(spec)
spec.loader.exec_module(worker)


def estimate(rgb: np.ndarray, reset: bool) -> np.ndarray | None:
    if rgb[0, 0, 2] == 0:
        return None
    i = np.arange(worker.N_LANDMARKS)
    return np.stack([rgb.shape[1] - 1.0 - i, rgb[0, 0, 0] + 2.0 * i,
                     np.full(len(i), 1.0 if reset else 0.25)], axis=1)


worker.serve(estimate, 'fake 1.0', sys.stdin.buffer, sys.stdout.buffer)
