"""Inputs a stage reads beside its frame, taken when the frame is processed: they wake
nobody (`PolledTopic`): the latest calibration (`LatestIntrinsics`) and a camera's image of
the frame's stamp if it has come (`RecentImages`)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.type_support import check_is_valid_msg_type
from sensor_msgs.msg import CameraInfo, Image

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import MessageReader, StageMonitor, SubscribedWhile
from pose4d_ros.wire import intrinsics_from_msg, stamp_to_ns


class PolledTopic:
    """A subscription that wakes nobody: its messages wait in the DDS reader (the newest
    `profile.depth`) until the stage that uses them takes them (`take()`, in the thread
    that processes its frame).

    For inputs a stage reads beside its frame and never waits for (the latest camera_info,
    the image of the frame's stamp if it has come): taken through the executor, each such
    message was a wake-up of the node's Python thread, 0.13-0.3 ms of CPU at 30 fps whatever
    the message (a null subscriber on this host, docs/NOTES.md), while here it costs the
    DDS reader's copy alone. The subscription is rcl's, made without rclpy's `Subscription`
    (which an executor would serve); it is in the ROS graph as any other (`ros2 topic info`).
    `close()` destroys it (`close_inputs`: at deactivation and exit).
    """

    def __init__(self, node: Node, msg_type: type, topic: str, profile: object) -> None:
        self._type = msg_type
        check_is_valid_msg_type(msg_type)  # its type support loaded, as create_subscription does
        with node.handle:
            self._handle = _rclpy.Subscription(node.handle, msg_type, topic,
                                               profile.get_c_qos_profile())
        self._polled = node.__dict__.setdefault('polled_topics', [])
        self._polled.append(self)

    def take(self) -> list[bytes]:
        """The serialised messages come since the last take, oldest first."""
        out = []
        try:
            with self._handle:
                while (item := self._handle.take_message(self._type, True)) is not None:
                    out.append(item[0])
        except InvalidHandle:  # closed meanwhile (`SubscribedWhile`, a deactivation)
            pass
        return out

    def close(self) -> None:
        self._handle.destroy_when_not_in_use()
        if self in self._polled:
            self._polled.remove(self)


class LatestIntrinsics:
    """The intrinsics of the latest camera_info (for stages whose inputs carry none), taken
    when a frame asks for them (`latest()`, a `PolledTopic`).

    A camera sends the same calibration with every frame: a message whose bytes after its
    stamp are those of the last one read is not deserialised again."""

    def __init__(self, node: Node, monitor: StageMonitor,
                 topic: str = 'camera/color/camera_info') -> None:
        self.intrinsics: Intrinsics | None = None
        self._monitor = monitor
        self._read: bytes | None = None  # the bytes after the stamp of the last one read
        self._topic = PolledTopic(node, CameraInfo, topic, qos.SENSOR_QOS)
        self._message = MessageReader(node, CameraInfo, topic, monitor)

    def latest(self) -> Intrinsics | None:
        """The intrinsics of the newest valid camera_info come so far (None before the
        first); each one taken that is refused is counted as a bad input."""
        for data in self._topic.take():
            self._update(data)
        return self.intrinsics

    def _update(self, data: bytes) -> None:
        body = data[12:]  # bytes 0-3: the encapsulation, 4-11: the stamp
        if body == self._read or (msg := self._message(data)) is None:
            return
        try:
            self.intrinsics = intrinsics_from_msg(msg)
            self._read = body
        except ValueError as exc:
            self._read = None
            self._monitor.bad_input(f'camera_info refused: {exc}')


class RecentImages:
    """A camera's images of the last few stamps, for a stage that uses the one of its frame's
    stamp when it has come but never waits for it (the tracker's free-space check, the IK's
    depth, the foreground's masked colour): `at(stamp_ns)` is that image read by `read` (the
    nearest stamp within `slop_ns`), or None.

    The images wait in their DDS reader (a `PolledTopic`) until a frame asks: then those come
    since are read in place (`image_of_bytes`: their header and size, bytes that hold no
    Image counted as bad inputs), and the pixels of the one used are read. With `wanted`, the
    topic is subscribed only while `wanted()` (`SubscribedWhile`)."""

    def __init__(self, node: Node, monitor: StageMonitor, topic: str,
                 read: Callable[[Image], np.ndarray], *, slop_ns: int = 0,
                 wanted: Callable[[], bool] | None = None) -> None:
        self._recent: deque[tuple[int, object]] = deque(maxlen=qos.RECENT_QOS.depth)
        self._read = read
        self._slop_ns = slop_ns
        self._monitor = monitor
        self._image = MessageReader(node, Image, topic, monitor)
        self._topic: PolledTopic | None = None

        def make() -> PolledTopic:
            self._topic = PolledTopic(node, Image, topic, qos.RECENT_QOS)
            return self._topic

        if wanted is None:
            make()
        else:
            self.follow = SubscribedWhile(node, wanted, make)

    def at(self, stamp_ns: int) -> np.ndarray | None:
        topic = self._topic
        for data in (topic.take() if topic is not None else ()):
            if (msg := self._image(data)) is not None:
                self._recent.append((stamp_to_ns(msg.header.stamp), msg))
        if not self._recent:
            return None
        near, msg = min(self._recent, key=lambda item: abs(item[0] - stamp_ns))
        if abs(near - stamp_ns) > self._slop_ns:
            return None
        try:
            return self._read(msg)
        except ValueError as exc:
            self._monitor.bad_input(f'{self._image.name} at {near} ns refused: {exc}')
            return None
