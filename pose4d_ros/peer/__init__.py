"""The peer a user would pick instead of pose4d: MediaPipe Pose 0.10.21, for side-by-side runs.

`pose4d eval --peer mediapipe` and `pose4d bench --peer mediapipe` run MediaPipe on the same
frames as our pipeline. MediaPipe lives in its own venv (`make peer`: `.venv-peer`, pinned in
`requirements/peer.txt`), because it needs numpy<2 and opencv-contrib-python; `MediaPipePeer`
starts `worker.py` there as a subprocess and speaks the small binary protocol described in it.

Its 33 landmarks become our joints (`JOINT_LANDMARKS`): the head is the midpoint of the two
ears (MediaPipe has no head-centre landmark; the nose sits on the face's surface), the other
twelve are MediaPipe's own shoulder, elbow, wrist, hip, knee and ankle landmarks. MediaPipe's
left and right are the person's own sides, as ours. A joint's confidence is its landmark's
visibility (the ears' mean for the head). Each joint is lifted to 3-D exactly as our detector
lifts its parts: `core.camera.robust_depth` (median of the valid depths in a 7 x 7 window) and
`backproject`, without a foreground mask (a MediaPipe user has none).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, backproject, robust_depth
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.lifting import DEPTH_RADIUS_PX
from pose4d_ros.peer import worker

# Our joint <- the MediaPipe Pose landmarks it is the mean of (`PoseLandmark` numbers)
JOINT_LANDMARKS: dict[str, tuple[int, ...]] = {
    'head': (7, 8),  # LEFT_EAR, RIGHT_EAR
    'left_shoulder': (11,), 'left_elbow': (13,), 'left_wrist': (15,),
    'right_shoulder': (12,), 'right_elbow': (14,), 'right_wrist': (16,),
    'left_hip': (23,), 'left_knee': (25,), 'left_ankle': (27,),
    'right_hip': (24,), 'right_knee': (26,), 'right_ankle': (28,),
}
NAMES: tuple[str, ...] = tuple(JOINT_LANDMARKS)


class Peer(Protocol):
    """What a peer is to `pose4d eval` and `pose4d bench` (the verbs see no more of it).

    Attributes
    ----------
    name : its row's name, and the `--peer` name it is chosen by (`PEERS`).
    description : what it runs, for the record (e.g. 'mediapipe 0.10.21 pose ...').
    last_cpu_s : CPU seconds of the last `step`, every process and thread of it included.
    """

    name: str
    description: str
    last_cpu_s: float

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None, *, new_video: bool = False) -> JointSet:
        """One person's joints (any subset of our joint names) in one RGB frame, in 3-D where
        depth has a reading; all MISSING when it finds nobody. `new_video`: forget the frames
        before (a new take)."""

    def close(self) -> None:
        """Free what it holds (a worker process)."""


def peer_python() -> Path:
    """The peer venv's Python: $POSE4D_PEER_PYTHON, else `.venv-peer` beside the project's venv
    (where `make peer` puts it)."""
    env = os.environ.get('POSE4D_PEER_PYTHON')
    return Path(env) if env else Path(sys.prefix).parent / '.venv-peer' / 'bin' / 'python'


def worker_command() -> list[str]:
    """How to start the MediaPipe worker; ValueError (one line) when the peer venv is absent."""
    python = peer_python()
    if not os.access(python, os.X_OK):
        raise ValueError(f'--peer mediapipe needs MediaPipe 0.10.21 in its own venv: run '
                         f'`make peer` in the pose4d_ros checkout (no {python})')
    return [str(python), '-I', worker.__file__]


def joints_from_landmarks(landmarks: NDArray[np.floating]
                          ) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
    """Our joints from MediaPipe's landmarks.

    Parameters
    ----------
    landmarks : (33, 3) float pixel u, v and visibility of each landmark.

    Returns
    -------
    uv : (13, 2) float64 pixels of `NAMES`.
    confidence : (13,) float32, the landmarks' mean visibility.
    """
    lm = np.asarray(landmarks, np.float64)
    if lm.shape != (worker.N_LANDMARKS, 3):
        raise ValueError(f'MediaPipe Pose gives ({worker.N_LANDMARKS}, 3) landmarks, '
                         f'got {lm.shape}')
    uv = np.array([lm[list(idx), :2].mean(axis=0) for idx in JOINT_LANDMARKS.values()])
    conf = np.array([lm[list(idx), 2].mean() for idx in JOINT_LANDMARKS.values()], np.float32)
    return uv, np.clip(conf, 0.0, 1.0)


class MediaPipePeer:
    """MediaPipe Pose in its worker process, giving our joints in 3-D frame by frame.

    Parameters
    ----------
    command : how to start the worker (default `worker_command()`; tests give a fake one).
    depth_radius_px : half-size of the robust depth look-up's window (the detector's).

    Attributes
    ----------
    name : the row's name in `pose4d eval`.
    description : what the worker said it runs (e.g. 'mediapipe 0.10.21 pose ...').
    last_cpu_s : CPU seconds of the last frame: the worker's (every thread of it) and, for
        `step`, this thread's for the mapping and 3-D look-up.
    """

    name = 'mediapipe'

    def __init__(self, command: Sequence[str] | None = None, *,
                 depth_radius_px: int = DEPTH_RADIUS_PX) -> None:
        self.command = list(command) if command is not None else worker_command()
        self.depth_radius_px = depth_radius_px
        self.last_cpu_s = float('nan')
        self._log = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(self.command, stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=self._log)
        head = self._read(worker.HELLO.size)
        magic, n = worker.HELLO.unpack(head)
        if magic != b'P4DH':
            self.close()
            raise ValueError(f'{self.command[-1]}: not a peer worker (said {magic!r})')
        self.description = self._read(n).decode()

    def __enter__(self) -> MediaPipePeer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the worker (it stops when its input closes)."""
        if self._proc.stdin is not None and not self._proc.stdin.closed:
            try:
                self._proc.stdin.close()
            except BrokenPipeError:
                pass
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._log.close()

    def _failure(self, what: str) -> ValueError:
        self._proc.poll()
        self._log.seek(0)
        lines = [ln for ln in self._log.read().decode(errors='replace').splitlines()
                 if ln.strip()]
        why = lines[-1].strip() if lines else f'exit status {self._proc.returncode}'
        return ValueError(f'the MediaPipe worker ({" ".join(self.command)}) {what}: {why}')

    def _read(self, n: int) -> bytes:
        try:
            data = worker.read_exact(self._proc.stdout, n)
        except EOFError:
            data = b''
        if len(data) != n:
            raise self._failure('stopped')
        return data

    def landmarks(self, color: NDArray[np.uint8], *, new_video: bool = False
                  ) -> NDArray[np.float32] | None:
        """The worker's (33, 3) landmarks (pixel u, v, visibility) of one RGB frame, None when
        it found no person; `new_video` resets its tracking first."""
        color = np.ascontiguousarray(color, np.uint8)
        if color.ndim != 3 or color.shape[2] != 3:
            raise ValueError(f'colour image must be (H, W, 3) RGB, got shape {color.shape}')
        h, w = color.shape[:2]
        try:
            self._proc.stdin.write(worker.FRAME.pack(b'P4DF', worker.RESET if new_video else 0,
                                                     w, h))
            self._proc.stdin.write(memoryview(color).cast('B'))
            self._proc.stdin.flush()
        except BrokenPipeError:
            raise self._failure('stopped') from None
        magic, n, cpu_s = worker.RESULT.unpack(self._read(worker.RESULT.size))
        if magic != b'P4DR':
            raise self._failure(f'sent {magic!r} instead of a result')
        self.last_cpu_s = cpu_s
        if n == 0:
            return None
        return np.frombuffer(self._read(n * 12), '<f4').reshape(n, 3)

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None, *, new_video: bool = False) -> JointSet:
        """Our joints (`NAMES`) of one frame, in 3-D where the depth has a reading; all MISSING
        when MediaPipe finds no person."""
        lm = self.landmarks(color, new_video=new_video)
        if lm is None:
            return JointSet.missing(NAMES)
        start = time.thread_time()
        uv, conf = joints_from_landmarks(lm)
        xyz = None
        if depth_m is not None and intrinsics is not None:
            z = robust_depth(depth_m, uv, radius=self.depth_radius_px)
            xyz = backproject(uv, z, intrinsics)
        joints = JointSet(NAMES, uv, xyz, confidence=conf, score=float(conf.mean()))
        self.last_cpu_s += time.thread_time() - start
        return joints


# Every peer, by the name `--peer` chooses it by: how to start one (a ValueError in one line when
# it cannot run here, e.g. its venv is absent). A new peer is a class like `MediaPipePeer` and a
# line here.
PEERS: dict[str, Callable[[], Peer]] = {'mediapipe': MediaPipePeer}


def make_peer(name: str) -> Peer:
    """The peer called `name` (`PEERS`), started."""
    try:
        start = PEERS[name]
    except KeyError:
        raise ValueError(f'no peer called {name!r}: one of {", ".join(PEERS)}') from None
    return start()
