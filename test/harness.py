"""Node-level test harness: run installed executables as `ros2 run` would, talk over Fast DDS.

`start(exe, params)` runs `<prefix>/lib/pose4d_ros/<exe> --ros-args -p name:=value ...` as a
subprocess (no launch files), found through the ament index exactly as `ros2 run` finds it;
`RunningNode.stop()` sends SIGINT and returns the exit status. `RosPeer` is the test's own
rclpy node with helpers to publish, collect and wait.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pose4d_ros.nodes.params import override_args

PACKAGE = 'pose4d_ros'


def executable(name: str) -> Path:
    """Path of an installed executable, looked up as `ros2 run pose4d_ros <name>` does."""
    from ament_index_python.packages import get_package_prefix

    return Path(get_package_prefix(PACKAGE)) / 'lib' / PACKAGE / name


class RunningNode:
    """A node executable running as a subprocess; its output goes to a log file."""

    def __init__(self, exe: str, params: dict[str, Any] | None = None,
                 remaps: dict[str, str] | None = None, *, log_dir: Path,
                 extra: list[str] | None = None) -> None:
        self.exe = exe
        cmd = [str(executable(exe)), '--ros-args', *override_args(params or {})]
        for src, dst in (remaps or {}).items():
            cmd += ['-r', f'{src}:={dst}']
        cmd += extra or []
        self.cmd = cmd
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = log_dir / f'{exe}-{time.monotonic_ns()}.log'
        self._log = self.log_path.open('w')
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT,
                                     env=dict(os.environ))

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f'{self.exe} did not exit within {timeout} s:\n'
                                 f'{self.output()}') from None

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> int:
        """Send `sig` (SIGINT = Ctrl-C) and return the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.wait(timeout)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        self._log.close()


def start(exe: str, params: dict[str, Any] | None = None, *, log_dir: Path,
          remaps: dict[str, str] | None = None) -> RunningNode:
    return RunningNode(exe, params, remaps, log_dir=log_dir)


class RosPeer:
    """The test's side of the graph: one rclpy node in its own context."""

    def __init__(self, name: str = 'pose4d_test_peer') -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.subscriptions: dict[str, Any] = {}

    def spin_until(self, done: Callable[[], bool], timeout: float, what: str = '') -> None:
        """Spin until `done()`; AssertionError after `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout} s waiting for {what or done}')
            self.executor.spin_once(timeout_sec=0.02)

    def wait(self, done: Callable[[], bool], timeout: float) -> bool:
        """Spin until `done()` or `timeout` seconds; whether it is done."""
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
        return done()

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)

    def send_until_answered(self, send: Callable[[], None], answered: Callable[[], bool],
                            what: str, *, tries: int = 15, timeout: float = 2.0) -> None:
        """`send()` until `answered()`, waiting `timeout` seconds for the answer each time: a
        best-effort reader drops what comes before it has matched our writer (camera_info
        too), so a message may have to be sent again. AssertionError after `tries` sends."""
        for _ in range(tries):
            send()
            if self.wait(answered, timeout):
                return
        raise AssertionError(f'no answer to {what} after {tries} sends')

    def collect(self, msg_type: type, topic: str, qos: Any = 10) -> list:
        """Subscribe and return the list that received messages are appended to."""
        received: list = []
        self.subscriptions[topic] = self.node.create_subscription(msg_type, topic,
                                                                  received.append, qos)
        return received

    def wait_for_subscribers(self, publisher: Any, count: int = 1, timeout: float = 10.0) -> None:
        self.spin_until(lambda: publisher.get_subscription_count() >= count, timeout,
                        f'{count} subscriber(s) on {publisher.topic_name}')

    def wait_for_publishers(self, topic: str, count: int = 1, timeout: float = 10.0) -> None:
        """Wait until `count` publishers are matched with our subscription on `topic` (or, with
        no subscription of ours, seen on the graph). A publisher seen on the graph may not be
        matched yet, and what it publishes before then is lost."""
        sub = self.subscriptions.get(topic)
        self.spin_until(lambda: (sub.get_publisher_count() if sub is not None
                                 else self.node.count_publishers(topic)) >= count, timeout,
                        f'{count} publisher(s) on {topic}')

    def call(self, srv_type: type, name: str, request: Any, timeout: float = 10.0) -> Any:
        """Call a service and return its answer."""
        client = self.node.create_client(srv_type, name)
        try:
            self.spin_until(client.service_is_ready, timeout, f'the service {name}')
            future = client.call_async(request)
            self.spin_until(future.done, timeout, f'the answer of {name}')
            return future.result()
        finally:
            self.node.destroy_client(client)

    def set_parameters(self, node: str, values: dict[str, Any], timeout: float = 10.0) -> list:
        """Set parameters of a running node through its parameter service, as
        `ros2 param set` does; returns one SetParametersResult per parameter."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        return self.call(SetParameters, f'/{node}/set_parameters', request, timeout).results

    def lifecycle_get(self, node: str, timeout: float = 10.0) -> str:
        """The node's lifecycle state, as `ros2 lifecycle get <node>` asks it (its get_state
        service): 'unconfigured', 'inactive', 'active' or 'finalized'."""
        from lifecycle_msgs.srv import GetState

        return self.call(GetState, f'/{node}/get_state', GetState.Request(),
                         timeout).current_state.label

    def lifecycle_set(self, node: str, transition: str, timeout: float = 60.0) -> bool:
        """`ros2 lifecycle set <node> <transition>` ('configure', 'activate', 'deactivate',
        'cleanup', 'shutdown'): as ros2lifecycle does, the label is looked up among the
        node's available transitions (False, as its 'Unknown transition requested', when it
        is not one of them), then requested by change_state; whether it succeeded."""
        from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions

        available = self.call(GetAvailableTransitions, f'/{node}/get_available_transitions',
                              GetAvailableTransitions.Request()).available_transitions
        # 'shutdown' is one label for three transitions, one from each primary state
        match = [t.transition for t in available if t.transition.label == transition]
        if not match:
            return False
        return self.call(ChangeState, f'/{node}/change_state',
                         ChangeState.Request(transition=match[0]), timeout).success

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def cpu_seconds(pid: int) -> float:
    """The CPU time (user + system, every thread) that process `pid` has used so far."""
    fields = Path(f'/proc/{pid}/stat').read_text().rpartition(')')[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def check_tf(skeletons: list, tf_messages: list, prefix: str = 'pose4d') -> int:
    """Check /tf against the skeletons: for each skeleton message, one TFMessage of its stamp
    with one transform per located joint (not MISSING, finite 3-D), from the skeleton's frame
    to `<prefix>/<track_id>/<joint>` at the joint's position (the message's other transforms,
    the REP 155 body frames, are not looked at here). Returns the transforms seen."""
    import math

    from pose4d_ros.core.joints import MISSING
    from pose4d_ros.wire import stamp_to_ns

    by_stamp = {stamp_to_ns(m.transforms[0].header.stamp): m for m in tf_messages}
    seen = 0
    for skeleton in skeletons:
        stamp = stamp_to_ns(skeleton.header.stamp)
        located = {f'{prefix}/{skeleton.track_id}/{j.name}': j for j in skeleton.joints
                   if j.source != MISSING and all(math.isfinite(c) for c in
                                                  (j.position.x, j.position.y, j.position.z))}
        assert located, f'skeleton at {stamp} ns has no located joint'
        transforms = [t for t in by_stamp[stamp].transforms
                      if t.child_frame_id.startswith(f'{prefix}/')]
        assert sorted(t.child_frame_id for t in transforms) == sorted(located)
        for t in transforms:
            assert t.header == skeleton.header
            j = located[t.child_frame_id]
            assert (t.transform.translation.x, t.transform.translation.y,
                    t.transform.translation.z) == (j.position.x, j.position.y, j.position.z)
            r = t.transform.rotation
            assert (r.x, r.y, r.z, r.w) == (0.0, 0.0, 0.0, 1.0)
        seen += len(transforms)
    return seen
