"""`recorder`: write named topics to an mcap rosbag2, losing nothing.

Finds each topic's type and its publishers' QoS on the graph (like `ros2 bag record`: reliable
only when every publisher is reliable), subscribes to the raw CDR bytes and writes them with
their receive time on the node's clock (with `use_sim_time:=true`, the replayed bag's /clock;
what comes before the first /clock gets its time).
On SIGINT or SIGTERM it first takes what is still on its way (nothing published before the
signal is lost), then closes the bag and moves it into place; until then it lives under a
hidden temporary name (.NAME.partial-PID), so a bag under the final name is always complete.
Every `recorder.flush_period_s` what was received is put on disk, so after a crash (`kill -9`)
`pose4d bag-repair` recovers all but the last moments; at start the recorder names the
unfinished recordings such crashes left beside its output.

Subscriptions
    every topic in `recorder.topics` (relative names; namespaces and remapping apply)

Parameters (config/recorder.yaml)
    recorder.output, recorder.topics, recorder.storage, recorder.compress, recorder.depth,
    recorder.flush_period_s
"""

from __future__ import annotations

import os
import signal
import threading
import time
from typing import Any

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

from pose4d_ros.datasets import bag
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import executor, run
from pose4d_ros.nodes.convert import message_type
from pose4d_ros.nodes.params import NodeParams, Param, ParameterError


def _new_path(path: str) -> str | None:
    if not path:
        return 'no output given (set recorder.output:=/path/to/new_bag)'
    if os.path.exists(path):
        return f'{path!r} exists already; the recorder never overwrites a bag'
    parent = os.path.dirname(os.path.abspath(path))
    return None if os.path.isdir(parent) else f'{parent!r}: no such directory'


PARAMS = (
    Param('recorder.output', '', 'Directory of the new rosbag2 to write; must not exist.',
          check=_new_path, restart='the bag is created at start-up'),
    Param('recorder.topics', ['pose4d/skeleton'], 'Topics to record (relative names).',
          check=lambda v: None if v and all(v) else 'give at least one topic name',
          restart='the topics are looked up and subscribed to from start-up'),
    Param('recorder.storage', 'mcap', 'rosbag2 storage plugin.', choices=('mcap', 'sqlite3'),
          restart='the bag is created at start-up'),
    Param('recorder.compress', True, 'zstd chunk compression (mcap).',
          restart='the bag is created at start-up'),
    Param('recorder.depth', 1000, 'Subscription queue depth, messages.', range=(1, 100000),
          restart='the subscriptions are made with it'),
    Param('recorder.flush_period_s', 0.5, 'Put what was received on disk this often, seconds '
          '(what a crash can lose).', range=(0.05, 60.0),
          restart='the flush timer is made with it'),
)


class RecorderNode(Node):
    """Bag recorder. Subscribes to `recorder.topics`; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('recorder')
        p = NodeParams(self, PARAMS).values
        self.depth = p['recorder.depth']
        self.topics = [self.resolve_topic_name(t.lstrip('/')) for t in p['recorder.topics']]
        try:
            self.writer = bag.BagWriter(p['recorder.output'], storage=p['recorder.storage'],
                                        compress=p['recorder.compress'])
        except (OSError, ValueError) as exc:
            raise ParameterError(f'parameter recorder.output: {exc}') from None
        self.subscriptions_: dict[str, Any] = {}
        self.received = 0
        self.early: list[tuple[str, bytes]] = []  # received before the sim clock started
        self.closed = False
        # on the wall clock: discovery and flushing must go on while a sim clock stands still
        wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(0.2, self.discover, clock=wall)
        self.flush_timer = self.create_timer(p['recorder.flush_period_s'], self.writer.flush,
                                             clock=wall)
        self.get_logger().info(f'recording {", ".join(self.topics)} to {self.writer.path}')
        for partial in bag.partial_recordings(self.writer.path.parent):
            self.get_logger().warning(
                f'{partial}: an unfinished recording (its recorder was killed); '
                f'`pose4d bag-repair {partial}` turns what it holds into a bag')
        self.discover()

    def discover(self) -> None:
        """Subscribe to each wanted topic once its type is known on the graph."""
        types = dict(self.get_topic_names_and_types())
        for topic in self.topics:
            if topic in self.subscriptions_ or topic not in types:
                continue
            msgtype = types[topic][0]
            pubs = self.get_publishers_info_by_topic(topic)
            if not pubs:
                continue
            profile = qos.matching_subscription([i.qos_profile for i in pubs], self.depth)
            offered = bag.make_qos(
                reliable=profile.reliability == ReliabilityPolicy.RELIABLE,
                depth=pubs[0].qos_profile.depth or 10,
                transient_local=profile.durability == DurabilityPolicy.TRANSIENT_LOCAL)
            self.writer.add_topic(topic, msgtype, [offered])
            self.subscriptions_[topic] = self.create_subscription(
                message_type(msgtype), topic, self._writer_for(topic), profile, raw=True)
            self.get_logger().info(f'subscribed to {topic} [{msgtype}] '
                                   f'({profile.reliability.name.lower()})')
        if len(self.subscriptions_) == len(self.topics):
            self.timer.cancel()

    def _writer_for(self, topic: str):
        def write(data: bytes) -> None:
            self.received += 1
            now = self.get_clock().now().nanoseconds
            if now == 0:  # sim time whose first /clock is still on its way
                self.early.append((topic, data))
                return
            for early in self.early:  # stamped with the clock's first time
                self.writer.write(early[0], now, early[1])
            self.early.clear()
            self.writer.write(topic, now, data)
        return write

    def drain(self, executor: Executor, *, quiet_s: float = 0.3,
              limit_s: float = 3.0) -> None:
        """Take messages still on their way until none came for `quiet_s` (at most
        `limit_s`)."""
        start = last = time.monotonic()
        count = self.received
        while time.monotonic() - start < limit_s and time.monotonic() - last < quiet_s:
            executor.spin_once(timeout_sec=0.05)
            if self.received != count:
                count, last = self.received, time.monotonic()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for topic, data in self.early:  # the clock never started
            self.writer.write(topic, 0, data)
        path = self.writer.close()
        counts = ', '.join(f'{t} {n}' for t, n in self.writer.counts.items()) or 'nothing'
        # the context may be shut down already (signal): log without rosout
        rclpy.logging.get_logger(self.get_logger().name).info(
            f'wrote {self.received} messages to {path}: {counts}')


_stop = threading.Event()


def record(node: RecorderNode) -> None:
    """Spin until SIGINT or SIGTERM, then drain what publishers sent before it."""
    ex = executor(node)
    while not _stop.is_set():
        ex.spin_once(timeout_sec=0.1)
    node.drain(ex)


def main(args: list[str] | None = None) -> int:
    for sig in (signal.SIGINT, signal.SIGTERM):  # from the start: a signal is never lost
        signal.signal(sig, lambda *_: _stop.set())
    return run(RecorderNode, args, record, signal_handlers=False)
