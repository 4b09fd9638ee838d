"""`pose4d demo`: the main job (`make demo`).

Replays the bundled sample bag (synthetic RGB-D person, held-out real motion) at 1x through the
node graph, each stage its own process started exactly as `ros2 run` starts it (no launch
files): replay -> foreground -> detector -> tracker -> ik, and a recorder. Then it scores the
recorded /pose4d/skeleton against the bag's ground truth, runs the same core offline over the
same bag (what `pose4d eval` does) for comparison, checks the joints the graph put on /tf
against the skeletons, and writes out/overlay.mp4 (a video frame per skeleton out: the skeleton
drawn by joint source, the ground truth, the frame's latency), out/overlay.png (four of those
frames) and out/results.json.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pose4d_ros.cli._dpm import load_frames
from pose4d_ros.cli.eval import format_table
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.draw import draw_skeleton, legend
from pose4d_ros.core.files import write_atomic, write_json
from pose4d_ros.core.joints import MISSING, JointSet
from pose4d_ros.core.pipeline import limb_bones
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.datasets import bag, cad60_bag
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.datasets.messages import joints_from_msg, stamp_to_ns
from pose4d_ros.models import model_path

STAGES = ('foreground', 'detector', 'tracker', 'ik')
RECORDED = ('pose4d/skeleton', 'pose4d/parts', 'pose4d/parts/tracked', '/tf')
# topic -> subscribers that must be connected before the bag plays
PIPELINE_CONNECTIONS = {
    'camera/color/image_raw': 1, 'camera/depth/image_raw': 1, 'pose4d/skeleton': 2}
CONNECTIONS = {
    'camera/color/image_raw': 1, 'camera/depth/image_raw': 1,
    'pose4d/foreground/color': 1, 'pose4d/foreground/depth': 2, 'pose4d/foreground/mask': 1,
    'pose4d/parts': 2, 'pose4d/parts/tracked': 2, 'pose4d/skeleton': 2,
}


def share_path(relative: str) -> Path:
    """A file of the package's share directory (installed share/pose4d_ros/<relative>, else
    the checkout's)."""
    for prefix in [*os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep), sys.prefix]:
        path = Path(prefix) / 'share' / 'pose4d_ros' / relative
        if prefix and path.exists():
            return path
    return Path(__file__).resolve().parents[2] / relative


def default_bag() -> Path:
    """The bundled sample bag."""
    return share_path('bags/sample')


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser('demo', help='replay the sample bag through the node graph and '
                              'score the skeleton', description=__doc__.split('\n\n')[1])
    p.add_argument('--bag', type=Path, default=None, help='bag to replay (default: the '
                   'bundled sample, with ground truth on cad60/skeleton)')
    p.add_argument('--out', type=Path, default=Path('out'), help='output directory')
    p.add_argument('--rate', type=float, default=1.0, help='replay speed (1 = real time)')
    p.add_argument('--model', default='rgbd_14', help='detector model (shipped name or .npz)')
    p.add_argument('--timeout', type=float, default=60.0,
                   help='seconds to wait for the graph to connect and to drain')
    p.set_defaults(func=run)


class _Graph:
    """The node processes of one demo run."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}

    def start(self, exe: str, params: dict[str, Any]) -> None:
        from pose4d_ros.nodes.params import override_args

        cmd = [str(Path(sys.prefix) / 'lib' / 'pose4d_ros' / exe), '--ros-args',
               *override_args(params)]
        self.logs[exe] = self.out / 'logs' / f'{exe}.log'
        self.logs[exe].parent.mkdir(parents=True, exist_ok=True)
        log = self.logs[exe].open('w')
        self.procs[exe] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                           env=dict(os.environ))

    def check_alive(self) -> None:
        for exe, proc in self.procs.items():
            if exe != 'replay' and proc.poll() is not None:
                raise OSError(f'{exe} exited with status {proc.returncode}; see '
                              f'{self.logs[exe]}:\n{self.tail(exe)}')

    def tail(self, exe: str, lines: int = 8) -> str:
        return '\n'.join(self.logs[exe].read_text().splitlines()[-lines:])

    def cpu_seconds(self) -> dict[str, float]:
        """CPU time (user + system) each running process has used so far (Linux /proc)."""
        tick = os.sysconf('SC_CLK_TCK')
        out = {}
        for exe, proc in self.procs.items():
            try:
                fields = Path(f'/proc/{proc.pid}/stat').read_text().rsplit(')', 1)[1].split()
                out[exe] = (int(fields[11]) + int(fields[12])) / tick
            except (OSError, IndexError, ValueError):
                continue
        return out

    def raise_unless_clean(self, codes: dict[str, int]) -> None:
        """OSError naming each process whose exit status (`stop`'s) is not 0."""
        bad = {exe: code for exe, code in codes.items() if code != 0}
        if bad:
            raise OSError('processes did not exit cleanly: ' + ', '.join(
                f'{exe} ({code}, see {self.logs[exe]})' for exe, code in bad.items()))

    def stop(self) -> dict[str, int]:
        """SIGINT every process (the recorder last, so it closes its bag after the graph)."""
        codes = {}
        order = [e for e in self.procs if e != 'recorder'] + ['recorder']
        for exe in order:
            proc = self.procs.get(exe)
            if proc is None:
                continue
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            try:
                codes[exe] = proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                codes[exe] = proc.wait(5)
        return codes


@dataclass(frozen=True)
class GraphRun:
    """What one replay of a bag through the node graph gave.

    Attributes
    ----------
    recorded : the bag the recorder wrote (skeleton, parts, tracked parts, /tf).
    frames : colour frames in the replayed bag.
    entered : {stamp: monotonic s} when each frame's camera_info reached this process.
    left : {stamp: monotonic s} when each frame's skeleton reached this process.
    logs : {executable: log file}.
    cpu_s : {executable: CPU seconds used while the bag played and drained} (replay's whole
        run).
    """

    recorded: Path
    frames: int
    entered: dict[int, float]
    left: dict[int, float]
    logs: dict[str, Path]
    cpu_s: dict[str, float]

    def latency_ms(self) -> np.ndarray:
        """Colour frame in -> skeleton out, per frame that came out (both seen here, on one
        clock: replayed stamps are the recording's, so now - stamp would not measure it)."""
        return np.array([(self.left[s] - self.entered[s]) * 1e3 for s in self.left
                         if s in self.entered])

    def input_rate_hz(self) -> float:
        t = np.sort(np.fromiter(self.entered.values(), float))
        return (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else float('nan')


def run_graph(bag_path: Path, out: Path, *, rate: float = 1.0, model: str = 'rgbd_14',
              timeout: float = 60.0, pipeline: bool = False, best_effort: bool = False
              ) -> GraphRun:
    """Replay `bag_path` through the graph, each node its own process as `ros2 run` starts
    it (or the single `pipeline` process), with a recorder; stop everything cleanly.
    `best_effort`: the replay publishes best effort, as camera drivers do."""
    import rclpy
    from pose4d_msgs.msg import JointArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.common import executor
    from pose4d_ros.nodes.convert import stamp_to_ns

    frames = bag.topics(bag_path)[cad60_bag.COLOR_TOPIC].count
    # this process and the nodes: Fast DDS with room for large frames (config/fastdds.xml)
    os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', str(share_path('config/fastdds.xml')))
    out.mkdir(parents=True, exist_ok=True)
    recorded = out / ('pipeline_run' if pipeline else 'graph_run')
    if recorded.exists():
        shutil.rmtree(recorded)
    graph = _Graph(out)
    rclpy.init()
    node = rclpy.create_node('pose4d_demo')
    left: dict[int, float] = {}
    entered: dict[int, float] = {}
    node.create_subscription(
        JointArray, 'pose4d/skeleton',
        lambda m: left.setdefault(stamp_to_ns(m.header.stamp), time.monotonic()),
        qos.OUTPUT_QOS)
    # best effort (as the replay may publish), with room for every frame of a few seconds: a
    # moment without the CPU must not cost this probe a frame the graph itself got
    node.create_subscription(
        CameraInfo, 'camera/color/camera_info',
        lambda m: entered.setdefault(stamp_to_ns(m.header.stamp), time.monotonic()),
        QoSProfile(depth=300, reliability=ReliabilityPolicy.BEST_EFFORT))
    ex = executor(node)
    stages = ('pipeline',) if pipeline else STAGES
    connections = PIPELINE_CONNECTIONS if pipeline else CONNECTIONS
    try:
        graph.start('recorder', {'recorder.output': str(recorded),
                                 'recorder.topics': list(RECORDED)})
        for exe in stages:
            graph.start(exe, {'detector.model': model} if exe in ('detector', 'pipeline')
                        else {})
        deadline = time.monotonic() + timeout
        while True:
            graph.check_alive()
            lacking = {t: n for t, n in connections.items() if node.count_subscribers(t) < n}
            if not lacking:
                break
            if time.monotonic() > deadline:
                raise OSError(f'the graph did not connect within {timeout} s: too few '
                              f'subscribers on {", ".join(lacking)}')
            ex.spin_once(timeout_sec=0.1)
        cpu_before = graph.cpu_seconds()
        t_play = time.monotonic()
        # the replay plays once it has matched every subscriber seen here (this one too)
        played = [t.lstrip('/') for t in bag.topics(bag_path) if t.startswith('/camera/')]
        graph.start('replay', {'replay.bag': str(bag_path), 'replay.rate': rate,
                               'replay.best_effort': best_effort,
                               'replay.topics': played, 'replay.delay_s': 0.5,
                               'replay.wait_for_subscribers': [
                                   f'{t}={node.count_subscribers(t)}' for t in played]})
        replay = graph.procs['replay']
        replay_cpu = 0.0
        while replay.poll() is None:
            graph.check_alive()
            replay_cpu = graph.cpu_seconds().get('replay', replay_cpu)
            ex.spin_once(timeout_sec=0.05)
        if replay.returncode != 0:
            raise OSError(f'replay failed ({replay.returncode}):\n{graph.tail("replay")}')
        # drain: until every frame is out, or nothing has come for 3 s
        while len(left) < frames:
            if time.monotonic() - max(max(left.values(), default=t_play), t_play) > 3.0:
                break
            ex.spin_once(timeout_sec=0.05)
        cpu = {exe: t - cpu_before.get(exe, 0.0) for exe, t in graph.cpu_seconds().items()}
        cpu['replay'] = replay_cpu
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        codes = graph.stop()
    graph.raise_unless_clean(codes)
    return GraphRun(recorded, frames, entered, left, dict(graph.logs), cpu)


def run(args: argparse.Namespace) -> int:
    bag_path = args.bag or default_bag()
    if cad60_bag.SKELETON_TOPIC not in bag.topics(bag_path):
        raise ValueError(f'{bag_path}: no ground truth on {cad60_bag.SKELETON_TOPIC}')
    print(f'pose4d demo: replaying {bag_path} at {args.rate}x through '
          f'{" -> ".join(STAGES)} (one process each)')
    result = run_graph(bag_path, args.out, rate=args.rate, model=args.model,
                       timeout=args.timeout)
    return report(bag_path, result, args)


def report(bag_path: Path, result: GraphRun, args: argparse.Namespace) -> int:
    from pose4d_ros.cli._pipeline_eval import Row, pipeline_rows, score_rows

    frames = load_frames([str(bag_path)])
    skeletons = {}
    for m in bag.read_messages(result.recorded, ['/pose4d/skeleton']):
        msg = bag.deserialize(m)
        skeletons.setdefault(stamp_to_ns(msg.header.stamp), joints_from_msg(msg))
    graph = Row([skeletons.get(f.stamp_ns, JointSet.missing(SKELETON_14)) for f in frames])
    offline = pipeline_rows(frames, load_model(model_path(args.model)))
    tables = score_rows({'graph': graph, **offline}, frames)
    n_in, latency = result.frames, result.latency_ms()
    results = {
        'bag': str(bag_path), 'rate': args.rate, 'input_rate_hz': result.input_rate_hz(),
        'frames_in': n_in, 'skeletons_out': len(skeletons),
        'frames_lost': n_in - len(skeletons),
        'latency_ms': ({'p50': float(np.percentile(latency, 50)),
                        'p95': float(np.percentile(latency, 95)), 'n': int(latency.size)}
                       if latency.size else None),
        'tf': tf_per_skeleton(result.recorded, skeletons),
        'graph': tables.pop('graph'), 'offline': tables,
    }
    print(format_table({'graph (live, rgbd+kf+ik)': results['graph'],
                        **{f'offline {k}': v for k, v in tables.items()}}, n_in))
    print(f'\nframes in {n_in} (replayed at {result.input_rate_hz():.1f} Hz), skeletons out '
          f'{len(skeletons)}, lost {n_in - len(skeletons)}')
    if latency.size:
        print(f'latency colour frame -> /pose4d/skeleton: p50 {results["latency_ms"]["p50"]:.1f}'
              f' ms, p95 {results["latency_ms"]["p95"]:.1f} ms (n = {latency.size})')
    tf = results['tf']
    print(f'/tf: {tf["transforms"]} transforms, one per located joint, stamped like the '
          f'skeleton, for {tf["matching"]} of {tf["skeletons"]} skeletons')
    overlay = overlay_picture(frames, graph.preds)
    ok, png = cv2.imencode('.png', overlay[:, :, ::-1])
    if not ok:
        raise ValueError(f'could not encode the overlay picture ({overlay.shape})')
    write_atomic(args.out / 'overlay.png', png.tobytes())
    latencies = {s: (result.left[s] - result.entered[s]) * 1e3 for s in result.left
                 if s in result.entered}
    shown = [(f, skeletons[f.stamp_ns], latencies.get(f.stamp_ns)) for f in frames
             if f.stamp_ns in skeletons]
    write_video(args.out / 'overlay.mp4', (overlay_frame(*x) for x in shown),
                fps=result.input_rate_hz())
    write_json(args.out / 'results.json', results, indent=1)
    print(f'wrote {args.out / "overlay.mp4"} ({len(shown)} frames), '
          f'{args.out / "overlay.png"} and {args.out / "results.json"}')
    return 0 if len(skeletons) else 1


def tf_per_skeleton(recorded: Path, skeletons: dict[int, JointSet], *,
                    prefix: str = 'pose4d') -> dict[str, int]:
    """The recorded /tf against the recorded skeletons: `matching` counts the skeletons whose
    stamp has exactly one transform per located joint (`<prefix>/<track>/<joint>`) on /tf."""
    from pose4d_ros.nodes.convert import joint_frame

    frames: dict[int, list[str]] = {}
    for m in bag.read_messages(recorded, ['/tf']):
        for t in bag.deserialize(m).transforms:
            frames.setdefault(stamp_to_ns(t.header.stamp), []).append(t.child_frame_id)
    matching = 0
    for stamp, joints in skeletons.items():
        located = (joints.source != MISSING) & np.isfinite(joints.xyz).all(axis=1)
        want = [joint_frame(prefix, joints.track_id, name)
                for name, ok in zip(joints.names, located, strict=True) if ok]
        matching += sorted(frames.get(stamp, [])) == sorted(want)
    return {'skeletons': len(skeletons), 'matching': matching,
            'transforms': sum(len(f) for f in frames.values())}


def overlay_frame(frame: Frame, skeleton: JointSet, latency_ms: float | None) -> np.ndarray:
    """One video frame (RGB): the skeleton by joint source on the frame, the ground truth
    crossed, the frame's latency from camera to /pose4d/skeleton, and the legend."""
    img = draw_skeleton(frame.color, skeleton, limb_bones(), truth_uv=frame.truth.uv)
    text = f'latency {latency_ms:.0f} ms' if latency_ms is not None else 'latency unknown'
    for colour, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        cv2.putText(img, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, width,
                    cv2.LINE_AA)
    return np.vstack([img, legend(img.shape[1])])


def write_video(path: Path, frames: Iterable[np.ndarray], *, fps: float) -> int:
    """RGB frames of one size into an MPEG-4 video (OpenCV's `mp4v`, which OpenCV, ffmpeg and
    common players read), written under a temporary name and renamed when complete; returns
    the number of frames. `fps` that is not finite and positive becomes 30."""
    fps = fps if np.isfinite(fps) and fps > 0 else 30.0
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f'.{path.stem}.{os.getpid()}.tmp{path.suffix}')
    writer, n = None, 0
    try:
        for img in frames:
            if writer is None:
                h, w = img.shape[:2]
                writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*'mp4v'), fps, (w, h))
                if not writer.isOpened():
                    raise OSError(f'{path}: OpenCV cannot write an mp4v video here')
            writer.write(np.ascontiguousarray(img[:, :, ::-1]))
            n += 1
        if writer is None:
            raise ValueError(f'{path}: no frames to write')
        writer.release()
        os.replace(tmp, path)
    finally:
        if writer is not None:
            writer.release()
        tmp.unlink(missing_ok=True)
    return n


def overlay_picture(frames: list[Frame], skeletons: list[JointSet], n: int = 4) -> np.ndarray:
    """n frames spread over the bag, skeletons drawn by joint source, ground truth crossed."""
    bones = limb_bones()
    tiles = [draw_skeleton(frames[i].color, skeletons[i], bones, truth_uv=frames[i].truth.uv)
             for i in np.linspace(0, len(frames) - 1, n).astype(int)]
    row = np.hstack(tiles)
    return np.vstack([row, legend(row.shape[1])])
