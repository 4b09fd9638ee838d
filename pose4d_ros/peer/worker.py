"""The MediaPipe Pose worker: a program of its own, run by the peer venv's Python (`make peer`).

    .venv-peer/bin/python -I pose4d_ros/peer/worker.py

MediaPipe 0.10.21 needs numpy<2 and opencv-contrib-python, which clash with the project's pins,
so it runs in its own virtual environment and this file imports only the standard library and
numpy at the top (MediaPipe inside `main`): never `pose4d_ros`. `pose4d_ros.peer` starts it as
a subprocess and imports this module for the protocol below, so both ends share one definition.

Protocol (little-endian, over the worker's stdin and stdout):

- worker -> host, once at start: `HELLO` (b'P4DH', n) and n bytes of UTF-8 text naming the
  peer and its settings (e.g. 'mediapipe 0.10.21 pose model_complexity=1 video').
- host -> worker, per frame: `FRAME` (b'P4DF', flags, width, height) and width * height * 3
  bytes of RGB, row by row. Flag `RESET` (bit 0): a new video starts with this frame.
- worker -> host, per frame: `RESULT` (b'P4DR', n, cpu_s) and n * 3 float32: each landmark's
  pixel u, v (the project's convention: (0, 0) is the centre of the top-left pixel) and its
  visibility; n is 0 when no person was found. cpu_s is the worker's CPU time for the frame
  (`time.process_time`: every thread of the process, MediaPipe's own threads included).
- The host closes stdin to end the worker.

MediaPipe Pose runs as a user tracking a video would run it: `static_image_mode=False` (video
mode: the person found in one frame seeds the next, landmarks smoothed over time), reset at the
start of each video.
"""

from __future__ import annotations

import os
import struct
import sys
import time
from collections.abc import Callable
from typing import BinaryIO

import numpy as np

HELLO = struct.Struct('<4sI')
FRAME = struct.Struct('<4sIII')
RESULT = struct.Struct('<4sId')
RESET = 1
N_LANDMARKS = 33
# The full pose model: the one MediaPipe 0.10.21 carries in its wheel (0 and 2 are downloaded at
# first use)
MODEL_COMPLEXITY = 1

# (rgb (H, W, 3) uint8, reset) -> ((N_LANDMARKS, 3) float32 u, v, visibility, or None)
Estimator = Callable[[np.ndarray, bool], np.ndarray | None]


def read_exact(stream: BinaryIO, n: int) -> bytes:
    """n bytes from `stream`; b'' at a clean end of stream; EOFError when it ends mid-record."""
    chunks, got = [], 0
    while got < n:
        chunk = stream.read(n - got)
        if not chunk:
            if got:
                raise EOFError(f'stream ended after {got} of {n} bytes')
            return b''
        chunks.append(chunk)
        got += len(chunk)
    return b''.join(chunks)


def serve(estimator: Estimator, hello: str, stdin: BinaryIO, stdout: BinaryIO) -> None:
    """Answer frames from `stdin` until it closes."""
    text = hello.encode()
    stdout.write(HELLO.pack(b'P4DH', len(text)) + text)
    stdout.flush()
    while True:
        head = read_exact(stdin, FRAME.size)
        if not head:
            return
        magic, flags, width, height = FRAME.unpack(head)
        if magic != b'P4DF':
            raise ValueError(f'bad frame header {magic!r} (expected P4DF)')
        data = read_exact(stdin, width * height * 3)
        if len(data) != width * height * 3:
            raise EOFError(f'stream ended inside a {width}x{height} frame')
        rgb = np.frombuffer(data, np.uint8).reshape(height, width, 3)
        t0 = time.process_time()
        landmarks = estimator(rgb, bool(flags & RESET))
        cpu_s = time.process_time() - t0
        out = (np.zeros((0, 3), '<f4') if landmarks is None
               else np.asarray(landmarks, '<f4').reshape(-1, 3))
        stdout.write(RESULT.pack(b'P4DR', len(out), cpu_s) + out.tobytes())
        stdout.flush()


def mediapipe_estimator(model_complexity: int) -> tuple[Estimator, str]:
    """MediaPipe Pose in video mode, and the text that names it."""
    import mediapipe as mp

    pose = mp.solutions.pose.Pose(static_image_mode=False, model_complexity=model_complexity)

    def estimate(rgb: np.ndarray, reset: bool) -> np.ndarray | None:
        if reset:
            pose.reset()
        result = pose.process(rgb)
        if result.pose_landmarks is None:
            return None
        h, w = rgb.shape[:2]
        # MediaPipe's normalised x, y span the image from edge to edge (0 = the left edge of
        # the first pixel): minus half a pixel for pixel centres
        return np.array([(lm.x * w - 0.5, lm.y * h - 0.5, lm.visibility)
                         for lm in result.pose_landmarks.landmark], np.float32)

    return estimate, (f'mediapipe {mp.__version__} pose model_complexity={model_complexity} '
                      'video')


def main() -> int:
    # the protocol owns the real stdout; anything a library prints goes to stderr
    protocol_out = os.fdopen(os.dup(sys.stdout.fileno()), 'wb')
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    estimator, hello = mediapipe_estimator(MODEL_COMPLEXITY)
    serve(estimator, hello, sys.stdin.buffer, protocol_out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
