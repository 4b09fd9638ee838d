"""The node graph run as `ros2 run` runs it, each stage its own process (no launch files):
replay -> foreground -> detector -> tracker -> ik (or the single `pipeline` process), and a
recorder; `run_graph` replays a bag through it, times it and stops everything cleanly, and
`tf_per_skeleton` checks the joints the graph put on /tf against its skeletons. What
`pose4d demo`, `pose4d bench --graph` and the soak test run."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pose4d_ros.core.joints import MISSING, JointSet
from pose4d_ros.datasets import bag, cad60_bag
from pose4d_ros.wire import joints_from_msg, stamp_to_ns

STAGES = ('foreground', 'detector', 'tracker', 'ik')
# the processes of each graph: a node per stage, those four nodes in one process, the one node
GRAPHS = {'nodes': STAGES, 'composed': ('composed',), 'pipeline': ('pipeline',)}
# what a user of the skeletons subscribes to: the intermediate topics are published on demand
RECORDED = ('pose4d/skeleton', 'pose4d/skeletons', '/tf')
# topic -> subscribers that must be connected before the bag plays
PIPELINE_CONNECTIONS = {
    'camera/color/image_raw': 1, 'camera/depth/image_raw': 1, 'pose4d/skeleton': 2}
CONNECTIONS = {
    'camera/color/image_raw': 1, 'camera/depth/image_raw': 2, 'camera/color/camera_info': 5,
    'pose4d/foreground/depth': 2, 'pose4d/foreground/mask': 1, 'pose4d/parts/people': 1,
    'pose4d/parts/tracked/people': 1, 'pose4d/skeleton': 2,
}


def share_path(relative: str) -> Path:
    """A file of the package's share directory (installed share/pose4d_ros/<relative>, else
    the checkout's)."""
    for prefix in [*os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep), sys.prefix]:
        path = Path(prefix) / 'share' / 'pose4d_ros' / relative
        if prefix and path.exists():
            return path
    return Path(__file__).resolve().parents[2] / relative


# The bundled sample bags (`make sample-bag`): one person, then two (ground truth of each)
SAMPLE_BAGS = ('sample', 'sample_people2')


def default_bag(name: str = SAMPLE_BAGS[0]) -> Path:
    """A bundled sample bag (default: the one-person one)."""
    return share_path(f'bags/{name}')


class Graph:
    """The node processes of one demo run."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}

    def start(self, exe: str, params: dict[str, Any]) -> None:
        from pose4d_ros.nodes.params import override_args

        self._spawn(exe, [str(Path(sys.prefix) / 'lib' / 'pose4d_ros' / exe), '--ros-args',
                          *override_args(params)])

    def _spawn(self, name: str, cmd: list[str]) -> None:
        """Start `cmd` as process `name`, its output in `<out>/logs/<name>.log`."""
        self.logs[name] = self.out / 'logs' / f'{name}.log'
        self.logs[name].parent.mkdir(parents=True, exist_ok=True)
        self.procs[name] = subprocess.Popen(cmd, stdout=self.logs[name].open('w'),
                                            stderr=subprocess.STDOUT, env=dict(os.environ))

    def start_load(self, kind: str, nodes: list[str]) -> None:
        """A `graph.load` process beside the graph (named `load_<kind>` here and in the logs)."""
        from pose4d_ros.graph.load import LOADS

        if kind not in LOADS:
            raise ValueError(f'load {kind!r}: expected one of {LOADS}')
        self._spawn(f'load_{kind}', [sys.executable, '-m', 'pose4d_ros.graph.load', kind, *nodes])

    def check_alive(self) -> None:
        for exe, proc in self.procs.items():
            if exe != 'replay' and proc.poll() is not None:
                raise OSError(f'{exe} exited with status {proc.returncode}; see '
                              f'{self.logs[exe]}:\n{self.tail(exe)}')

    def tail(self, exe: str, lines: int = 8) -> str:
        return '\n'.join(self.logs[exe].read_text().splitlines()[-lines:])

    def cpu_seconds(self) -> dict[str, float]:
        """CPU time (user + system) each running process has used so far (Linux /proc)."""
        out = {}
        for exe, proc in self.procs.items():
            try:
                out[exe] = _cpu_s(Path(f'/proc/{proc.pid}/stat'))
            except (OSError, IndexError, ValueError):
                continue
        return out

    def thread_seconds(self) -> dict[str, dict[str, float]]:
        """CPU time each running process's threads have used so far, by kind (`THREADS`):
        `executor` (the main thread, which spins the node), `dds` (Fast DDS's, named
        `dds.*`) and `frames`, the rest of the process's: the frame worker, any threads of
        the libraries it calls, and threads that ended (a thread's time stays in its
        process's when it ends, not under /proc/PID/task: counted by thread alone, a
        thread that ended between two readings made the kinds add up to less than the
        process, 32.2 against 33.3 ms a frame of the pipeline node on a slow machine)."""
        out: dict[str, dict[str, float]] = {}
        for exe, proc in self.procs.items():
            kinds = dict.fromkeys(THREADS, 0.0)
            try:
                total = _cpu_s(Path(f'/proc/{proc.pid}/stat'))
                for task in Path(f'/proc/{proc.pid}/task').iterdir():
                    if int(task.name) == proc.pid:
                        kinds['executor'] += _cpu_s(task / 'stat')
                    elif (task / 'comm').read_text().startswith('dds.'):
                        kinds['dds'] += _cpu_s(task / 'stat')
            except (OSError, IndexError, ValueError):
                continue
            kinds['frames'] = total - kinds['executor'] - kinds['dds']
            out[exe] = kinds
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


# the kinds of a node process's threads (`Graph.thread_seconds`)
THREADS = ('executor', 'dds', 'frames')


def _cpu_s(stat: Path) -> float:
    """User + system CPU seconds in a /proc `stat` file (a process's or a thread's)."""
    fields = stat.read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


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
    dropped : {stage: frames it dropped} (`dropped` on its last /diagnostics, which comes
        after the last frame).
    thread_s : {executable: {thread kind: CPU seconds}} over the same span as `cpu_s`
        (`Graph.thread_seconds`; not the replay's).
    """

    recorded: Path
    frames: int
    entered: dict[int, float]
    left: dict[int, float]
    logs: dict[str, Path]
    cpu_s: dict[str, float]
    dropped: dict[str, int] = field(default_factory=dict)
    thread_s: dict[str, dict[str, float]] = field(default_factory=dict)

    def latency_ms(self) -> np.ndarray:
        """Colour frame in -> skeleton out, per frame that came out (both seen here, on one
        clock: replayed stamps are the recording's, so now - stamp would not measure it)."""
        return np.array([(self.left[s] - self.entered[s]) * 1e3 for s in self.left
                         if s in self.entered])

    def input_rate_hz(self) -> float:
        t = np.sort(np.fromiter(self.entered.values(), float))
        return (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else float('nan')


def probe(node: Any) -> tuple[dict[int, float], dict[int, float], dict[str, dict[str, str]]]:
    """Subscribe `node` to what a graph is measured by, filled as `node` spins: {stamp:
    monotonic s} when each frame's colour camera_info reached this process (entered) and when
    its skeleton did (left), and {stage: its last /diagnostics values} (`run_graph`, and the
    two-host test's consumer)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from pose4d_msgs.msg import JointArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo

    from pose4d_ros.nodes import qos

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
    stages: dict[str, dict[str, str]] = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith('pose4d: '):
                stages[status.name.removeprefix('pose4d: ')] = {
                    kv.key: kv.value for kv in status.values}

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 100)
    return entered, left, stages


def graph_environment() -> None:
    """The DDS settings of this process and of the graph it starts, where the environment
    gives none: Fast DDS with room for large frames (config/fastdds.xml), and discovery on
    this host only (`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`: a demo or a bench is not to
    join, or be joined by, another machine's nodes; the Makefile sets the same)."""
    os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', str(share_path('config/fastdds.xml')))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def run_graph(bag_path: Path, out: Path, *, rate: float = 1.0, model: str = 'rgbd_14',
              timeout: float = 60.0, graph: str = 'nodes', best_effort: bool = False,
              load: Sequence[str] = ()) -> GraphRun:
    """Replay `bag_path` through a graph of `GRAPHS`, each process as `ros2 run` starts it
    (`nodes`: a process per stage; `composed`: the four nodes in one; `pipeline`: the one
    node), with a recorder; stop everything cleanly.
    `best_effort`: the replay publishes best effort, as camera drivers do. `load`: processes
    run beside the graph while the bag plays (`graph.load`: 'busy', 'query')."""
    import rclpy

    from pose4d_ros.nodes.common import executor

    frames = bag.topics(bag_path)[cad60_bag.COLOR_TOPIC].count
    graph_environment()
    out.mkdir(parents=True, exist_ok=True)
    pipeline = graph == 'pipeline'
    stages = GRAPHS[graph]
    recorded = out / ('graph_run' if graph == 'nodes' else f'{graph}_run')
    if recorded.exists():
        shutil.rmtree(recorded)
    running = Graph(out)
    rclpy.init()
    node = rclpy.create_node('pose4d_demo')
    entered, left, diagnostics = probe(node)
    ex = executor(node)
    connections = PIPELINE_CONNECTIONS if pipeline else CONNECTIONS
    try:
        running.start('recorder', {'recorder.output': str(recorded),
                                 'recorder.topics': list(RECORDED)})
        for exe in stages:
            running.start(exe, {'detector.model': model}
                        if exe in ('detector', 'composed', 'pipeline') else {})
        deadline = time.monotonic() + timeout
        while True:
            running.check_alive()
            lacking = {t: n for t, n in connections.items() if node.count_subscribers(t) < n}
            if not lacking:
                break
            if time.monotonic() > deadline:
                raise OSError(f'the graph did not connect within {timeout} s: too few '
                              f'subscribers on {", ".join(lacking)}')
            ex.spin_once(timeout_sec=0.1)
        for kind in load:  # started once the graph is up, as a user's commands would be
            running.start_load(kind, list(STAGES if graph == 'composed' else stages))
        cpu_before, threads_before = running.cpu_seconds(), running.thread_seconds()
        t_play = time.monotonic()
        # the replay plays once it has matched every subscriber seen here (this one too)
        played = [t.lstrip('/') for t in bag.topics(bag_path) if t.startswith('/camera/')]
        running.start('replay', {'replay.bag': str(bag_path), 'replay.rate': rate,
                               'replay.best_effort': best_effort,
                               'replay.topics': played, 'replay.delay_s': 0.5,
                               'replay.wait_for_subscribers': [
                                   f'{t}={node.count_subscribers(t)}' for t in played]})
        replay = running.procs['replay']
        replay_cpu = 0.0
        while replay.poll() is None:
            running.check_alive()
            replay_cpu = running.cpu_seconds().get('replay', replay_cpu)
            ex.spin_once(timeout_sec=0.05)
        if replay.returncode != 0:
            raise OSError(f'replay failed ({replay.returncode}):\n{running.tail("replay")}')
        # drain: until every frame is out, or nothing has come for 3 s
        while len(left) < frames:
            if time.monotonic() - max(max(left.values(), default=t_play), t_play) > 3.0:
                break
            ex.spin_once(timeout_sec=0.05)
        cpu = {exe: t - cpu_before.get(exe, 0.0) for exe, t in running.cpu_seconds().items()}
        threads = {exe: {kind: t - threads_before.get(exe, {}).get(kind, 0.0)
                         for kind, t in kinds.items()}
                   for exe, kinds in running.thread_seconds().items() if exe != 'replay'}
        cpu['replay'] = replay_cpu
        # each stage's /diagnostics of after its last frame (one a second)
        until = time.monotonic() + 1.2
        while time.monotonic() < until:
            ex.spin_once(timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        codes = running.stop()
    running.raise_unless_clean(codes)
    dropped = {stage: int(values.get('dropped', 0)) for stage, values in diagnostics.items()}
    return GraphRun(recorded, frames, entered, left, dict(running.logs), cpu, dropped, threads)


def tf_per_skeleton(recorded: Path, skeletons: dict[int, JointSet], *,
                    prefix: str = 'pose4d') -> dict[str, int]:
    """The recorded /tf against the recorded skeletons: `matching` counts the skeletons whose
    stamp has exactly one transform per located joint (`<prefix>/<track>/<joint>`) of every
    person of that frame (/pose4d/skeletons, where recorded; else the skeleton's own) on /tf
    (the other frames there, REP 155's body frames, are not counted)."""
    from pose4d_ros.wire import joint_frame

    frames: dict[int, list[str]] = {}
    for m in bag.read_messages(recorded, ['/tf']):
        for t in bag.deserialize(m).transforms:
            if t.child_frame_id.startswith(f'{prefix}/'):
                frames.setdefault(stamp_to_ns(t.header.stamp), []).append(t.child_frame_id)
    everyone: dict[int, list[JointSet]] = {}
    if '/pose4d/skeletons' in bag.topics(recorded):
        for m in bag.read_messages(recorded, ['/pose4d/skeletons']):
            msg = bag.deserialize(m)
            everyone.setdefault(stamp_to_ns(msg.header.stamp),
                                [joints_from_msg(s) for s in msg.skeletons])
    matching = 0
    for stamp, joints in skeletons.items():
        want = []
        for person in everyone.get(stamp, [joints]):
            located = (person.source != MISSING) & np.isfinite(person.xyz).all(axis=1)
            want += [joint_frame(prefix, person.track_id, name)
                     for name, ok in zip(person.names, located, strict=True) if ok]
        matching += sorted(frames.get(stamp, [])) == sorted(want)
    return {'skeletons': len(skeletons), 'matching': matching,
            'transforms': sum(len(f) for f in frames.values())}
