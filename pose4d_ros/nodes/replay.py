"""`replay`: play a rosbag2 (mcap or sqlite3) as a camera driver would.

Publishes each message's raw CDR bytes exactly as recorded, on its recorded topic with its
recorded QoS, paced by the recorded (bag) timestamps at `replay.rate`. This is what stands in for
the Kinect driver.

Publications
    every selected topic of the bag (names relative, so namespaces and remapping apply);
    /clock (rosgraph_msgs/Clock) when `replay.publish_clock` is true.

Parameters (config/replay.yaml)
    replay.bag, replay.rate, replay.loop, replay.start_offset_s, replay.topics,
    replay.publish_clock, replay.wait_for_subscribers, replay.wait_timeout_s, replay.delay_s
"""

from __future__ import annotations

import fnmatch
import os
import time
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from pose4d_ros.datasets import bag
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import InputFailure, executor, run
from pose4d_ros.nodes.convert import message_type, ns_to_stamp
from pose4d_ros.nodes.params import NodeParams, Param, ParameterError


def _exists(path: str) -> str | None:
    if not path:
        return 'no bag given (set replay.bag:=/path/to/bag)'
    return None if os.path.exists(path) else f'{path!r}: no such bag'


def subscriber_counts(entries: list[str]) -> list[tuple[str, int]]:
    """[(topic pattern, count)] from 'pattern=count' entries; ValueError names a bad one."""
    out = []
    for entry in entries:
        pattern, sep, count = entry.rpartition('=')
        if not sep or not pattern or not count.isdigit():
            raise ValueError(f'{entry!r} is not pattern=count (e.g. camera/*=1)')
        out.append((pattern.lstrip('/'), int(count)))
    return out


def _check_counts(entries: list[str]) -> str | None:
    try:
        subscriber_counts(entries)
    except ValueError as exc:
        return str(exc)
    return None


PARAMS = (
    Param('replay.bag', '', 'Path of the rosbag2 directory (mcap or sqlite3) to play.',
          check=_exists, restart='the bag is opened and its publishers made at start-up'),
    Param('replay.rate', 1.0, 'Playback speed factor; 1.0 = as recorded, 0 = as fast as '
          'possible.', range=(0.0, 100.0), live=True),
    Param('replay.loop', False, 'Start again from the beginning when the bag ends.', live=True),
    Param('replay.start_offset_s', 0.0, 'Skip this many seconds at the start of the bag.',
          range=(0.0, 1e6), restart='playing starts once, from there'),
    Param('replay.topics', ['*'], 'Topics to play: names or shell patterns (camera/*), '
          'without leading slash.',
          restart='the bag is opened and its publishers made at start-up'),
    Param('replay.best_effort', False, 'Publish every topic best effort (keep last 5), as '
          'camera drivers do, whatever QoS the bag recorded.',
          restart='the bag is opened and its publishers made at start-up'),
    Param('replay.publish_clock', False, 'Publish /clock with the bag time of each message '
          '(for use_sim_time).', restart='the bag is opened and its publishers made at start-up'),
    Param('replay.wait_for_subscribers', ['*=0'], 'Before playing, wait until the played '
          'topics have this many subscribers: pattern=count entries (camera/*=1, '
          'camera/color/camera_info=4; clock=2 for /clock with replay.publish_clock); a topic '
          'matched by several needs the largest count.',
          check=_check_counts, restart='it applies once, before playing'),
    Param('replay.wait_timeout_s', 10.0, 'Longest wait for subscribers, seconds.',
          range=(0.0, 3600.0), restart='it applies once, before playing'),
    Param('replay.delay_s', 0.0, 'Wait this long before playing (after the subscribers are '
          'there), seconds: discovery can match a subscriber to us a moment after we see it, '
          'and a best-effort subscriber drops what comes before.', range=(0.0, 3600.0),
          restart='it applies once, before playing'),
)


class ReplayNode(Node):
    """Bag player. Publishes the bag's topics; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('replay')
        self.params = NodeParams(self, PARAMS)
        p = self.cfg
        self.path: str = p['replay.bag']
        try:
            infos = bag.topics(self.path)
        except (OSError, ValueError) as exc:
            raise ParameterError(f'parameter replay.bag: {exc}') from None
        patterns = [t.lstrip('/') for t in p['replay.topics']]
        self.selected = [name for name in infos
                         if any(fnmatch.fnmatchcase(name.lstrip('/'), pat) for pat in patterns)]
        if not self.selected:
            raise ParameterError(f'parameter replay.topics: {patterns} match none of the bag\'s '
                                 f'topics {sorted(infos)}')
        self.publishers_: dict[str, Any] = {}
        for name in self.selected:
            info = infos[name]
            profile = (qos.SENSOR_QOS if p['replay.best_effort'] else
                       qos.from_bag(info.qos[0]) if info.qos else qos.OUTPUT_QOS)
            self.publishers_[name] = self.create_publisher(
                message_type(info.msgtype), name.lstrip('/'), profile)
        self.executor_ = executor(self)  # serves the parameter services while playing
        self.clock_pub = (self.create_publisher(Clock, '/clock', 10)
                          if p['replay.publish_clock'] else None)
        self.sent: dict[str, int] = dict.fromkeys(self.selected, 0)
        self.get_logger().info(
            f'replaying {self.path} at rate {p["replay.rate"]} '
            f'(loop={p["replay.loop"]}, offset {p["replay.start_offset_s"]} s): '
            + ', '.join(f'{n} [{infos[n].count}]' for n in self.selected))

    @property
    def cfg(self) -> dict[str, Any]:
        """The parameters' current values (replay.rate and replay.loop may change)."""
        return self.params.values

    def _sleep_until(self, deadline: float) -> None:
        """Wait on the wall clock while still serving the node's services."""
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            self.executor_.spin_once(timeout_sec=min(remaining, 0.05))

    def wait_for_subscribers(self) -> bool:
        counts = subscriber_counts(self.cfg['replay.wait_for_subscribers'])
        pubs = dict(self.publishers_)
        if self.clock_pub is not None:  # sim-time nodes that must not miss the clock
            pubs['/clock'] = self.clock_pub
        need = {name: max([c for pat, c in counts if fnmatch.fnmatchcase(name.lstrip('/'), pat)],
                          default=0)
                for name in pubs}

        def lacking() -> dict[str, int]:
            return {n: c for n, c in need.items() if pubs[n].get_subscription_count() < c}

        deadline = time.monotonic() + self.cfg['replay.wait_timeout_s']
        while lacking() and time.monotonic() < deadline:
            self._sleep_until(time.monotonic() + 0.05)
        if missing := lacking():
            self.get_logger().warning('playing although these topics have fewer subscribers '
                                      f'than asked: {missing}')
        return not missing

    def play_once(self) -> int:
        """Play the bag once; returns the number of messages published.

        Messages are paced from an anchor (a wall time and a bag time) at the rate; a new rate
        (`ros2 param set`) moves the anchor to the next message.
        """
        rate: float | None = None
        anchor_wall, anchor_ns = 0.0, 0
        count = 0
        start_ns = None
        for message in bag.read_messages(self.path, self.selected):
            if start_ns is None:
                start_ns = message.timestamp_ns + int(self.cfg['replay.start_offset_s'] * 1e9)
            if message.timestamp_ns < start_ns:
                continue
            if self.cfg['replay.rate'] != rate:
                rate = self.cfg['replay.rate']
                anchor_wall, anchor_ns = time.monotonic(), message.timestamp_ns
            if rate > 0:
                self._sleep_until(anchor_wall + (message.timestamp_ns - anchor_ns) * 1e-9 / rate)
            if self.clock_pub is not None:
                self.clock_pub.publish(Clock(clock=ns_to_stamp(message.timestamp_ns)))
            self.publishers_[message.topic].publish(message.data)
            self.sent[message.topic] += 1
            count += 1
        return count

    def play(self) -> None:
        self.wait_for_subscribers()
        self._sleep_until(time.monotonic() + self.cfg['replay.delay_s'])
        t0 = time.monotonic()
        rounds = 0
        while rclpy.ok():
            try:
                self.play_once()
            except ValueError as exc:  # a damaged bag: what came before the damage was sent
                raise InputFailure(f'{exc} (sent {sum(self.sent.values())} messages before '
                                   'it); stopping') from exc
            rounds += 1
            if not self.cfg['replay.loop']:
                break
        # Reliable subscribers must have everything before we go.
        for pub in self.publishers_.values():
            if pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE:
                pub.wait_for_all_acked(Duration(seconds=5))
        total = sum(self.sent.values())
        elapsed = time.monotonic() - t0
        self.get_logger().info(
            f'sent {total} messages in {elapsed:.2f} s ({rounds} pass(es)): '
            + ', '.join(f'{n} {c}' for n, c in self.sent.items()))


def main(args: list[str] | None = None) -> int:
    return run(ReplayNode, args, body=ReplayNode.play)
