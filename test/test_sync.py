"""Stamp pairing of colour and depth (exact, nearest within slop, never the latest) and the
nodes' frame queue."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import header_at

from pose4d_ros.core.sync import StampSync

MS = 1_000_000


def test_exact_pairs_in_any_arrival_order():
    sync = StampSync(2)
    assert sync.push(1, 100, 'd100') == []
    assert sync.push(0, 100, 'c100') == [(100, ('c100', 'd100'))]
    assert sync.push(0, 200, 'c200') == []  # depth of 200 not here yet: wait, do not take 100
    assert sync.push(1, 200, 'd200') == [(200, ('c200', 'd200'))]
    assert sync.dropped == [0, 0]


def test_exact_mode_never_takes_a_different_stamp():
    sync = StampSync(2)
    sync.push(1, 100, 'd100')
    assert sync.push(0, 133, 'c133') == []
    # depth moved past 133 without a match: the colour frame is dropped, not paired
    assert sync.push(1, 166, 'd166') == []
    assert sync.dropped[0] == 1
    assert sync.push(0, 166, 'c166') == [(166, ('c166', 'd166'))]
    assert sync.dropped[1] == 1  # d100 was never used


def test_nearest_within_slop():
    sync = StampSync(2, slop_ns=10 * MS)
    sync.push(1, 95 * MS, 'd95')
    sync.push(0, 100 * MS, 'c100')  # 5 ms away; a nearer depth could still come
    out = sync.push(1, 103 * MS, 'd103')
    assert out == [(100 * MS, ('c100', 'd103'))]
    assert sync.dropped == [0, 1]


def test_three_streams_and_loss():
    rng = np.random.default_rng(0)
    sync = StampSync(3)
    stamps = [k * 33 * MS for k in range(200)]
    lost = set(rng.choice(200, 20, replace=False).tolist())
    events = []
    for k, s in enumerate(stamps):
        for stream in rng.permutation(3):
            if stream == 2 and k in lost:
                continue
            events.extend(sync.push(int(stream), s, (int(stream), k)))
    got = [e[1][0][1] for e in events]
    # every frame with all three parts comes out once, in order, correctly paired
    assert got == [k for k in range(200) if k not in lost][: len(got)]
    assert len(got) >= 200 - len(lost) - 1
    assert all(items[0][1] == items[1][1] == items[2][1] for _, items in events)


def test_restarted_stream_is_reset():
    sync = StampSync(2)
    sync.push(1, 500, 'old')
    sync.push(1, 100, 'new')  # replay looped: stamps went back
    assert sync.push(0, 100, 'c') == [(100, ('c', 'new'))]


@pytest.mark.parametrize('kwargs', [{'n_streams': 1}, {'n_streams': 2, 'slop_ns': -1},
                                    {'n_streams': 2, 'queue_size': 0}])
def test_bad_arguments(kwargs):
    with pytest.raises(ValueError):
        StampSync(**kwargs)


class _Counter:
    """Stands in for the StageMonitor: counts what the queue drops."""

    stage = 'test'

    def __init__(self) -> None:
        self.drops = 0

    def dropped(self, n: int = 1) -> None:
        self.drops += n


def test_frame_queue_works_on_the_newest_frame_and_counts_the_dropped(ros):
    import threading

    from pose4d_ros.nodes.common import FrameQueue

    done: list[int] = []
    busy = threading.Event()

    def process(frame: int) -> None:
        busy.wait(5.0)  # the stage is busy until the test lets it go
        done.append(frame)

    monitor = _Counter()
    queue = FrameQueue(ros.node, process, monitor, size=1)  # the newest waits
    try:
        queue.submit(0)
        ros.spin_for(0.2)  # frame 0 is in hand
        for frame in range(1, 5):  # four frames while it is busy: only the newest waits
            queue.submit(frame)
        busy.set()
        ros.spin_until(lambda: len(done) == 2, 5.0, 'the newest frame')
        ros.spin_for(0.2)
        assert done == [0, 4] and monitor.drops == 3
        queue.submit(5)  # idle: a frame is processed at once
        ros.spin_until(lambda: done[-1] == 5, 5.0, 'the next frame')
        assert monitor.drops == 3
    finally:
        queue.close()


def test_people_inputs_are_processed_off_the_executor_on_the_newest_frame(ros):
    """A stage fed by `PeopleInputs` alone (the tracker) processes in a worker thread: the
    executor keeps taking messages while a frame is in hand, and only the newest
    `STAGE_QUEUE` (two) wait."""
    import threading

    from pose4d_msgs.msg import JointArray
    from std_msgs.msg import Header

    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.core.skeleton import PARTS_10
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.common import PeopleInputs
    from pose4d_ros.nodes.convert import joints_to_msg, ns_to_stamp

    done: list[int] = []
    threads: list[threading.Thread] = []
    busy = threading.Event()

    def process(people: list, header: Header, _: tuple) -> None:
        threads.append(threading.current_thread())
        busy.wait(5.0)  # the stage is busy until the test lets it go
        done.append(header.stamp.sec)

    monitor = _Counter()
    monitor.bad_input = lambda text: pytest.fail(text)
    PeopleInputs(ros.node, 'queue_test/people', 'queue_test/single', [], process, monitor)
    pub = ros.node.create_publisher(JointArray, 'queue_test/single', qos.OUTPUT_QOS)
    joints = JointSet.missing(PARTS_10.names)

    def send(sec: int) -> None:
        pub.publish(joints_to_msg(joints, Header(stamp=ns_to_stamp(sec * 10 ** 9),
                                                 frame_id='camera')))

    try:
        ros.spin_until(lambda: pub.get_subscription_count() > 0, 5.0, 'the subscription')
        send(1)
        ros.spin_until(lambda: threads, 5.0, 'frame 1 in hand')
        for sec in range(2, 6):  # four frames while it is busy: taken, the newest two wait
            send(sec)
            ros.spin_for(0.05)
        ros.spin_for(0.3)
        busy.set()
        ros.spin_until(lambda: len(done) == 3, 5.0, 'the newest frames')
        ros.spin_for(0.2)
        assert done == [1, 4, 5] and monitor.drops == 2
        assert threads[0] is not threading.current_thread()
    finally:
        for queue in ros.node.__dict__.get('frame_queues', []):
            queue.close()


def test_frame_queue_keeps_a_burst_in_order_up_to_its_size(ros):
    import threading

    from pose4d_ros.nodes.common import FrameQueue

    done: list[int] = []
    busy = threading.Event()
    monitor = _Counter()
    queue = FrameQueue(ros.node, lambda f: (busy.wait(5.0), done.append(f)), monitor, size=3)
    try:
        for frame in range(6):  # 0 in hand, 1-2 dropped, 3-5 wait
            queue.submit(frame)
            ros.spin_for(0.05)
        busy.set()
        ros.spin_until(lambda: len(done) == 4, 5.0, 'the burst')
        assert done == [0, 3, 4, 5] and monitor.drops == 2
    finally:
        queue.close()


def test_frame_queue_survives_an_error_in_a_frame(ros):
    from pose4d_ros.nodes.common import FrameQueue

    done: list[int] = []

    def process(frame: int) -> None:
        if frame == 0:
            raise RuntimeError('broken frame')
        done.append(frame)

    class Monitor(_Counter):
        bad = 0

        def bad_input(self, text: str) -> None:
            self.bad += 1

    monitor = Monitor()
    queue = FrameQueue(ros.node, process, monitor)
    try:
        queue.submit(0)
        ros.spin_for(0.1)
        queue.submit(1)
        ros.spin_until(lambda: done == [1], 5.0, 'the frame after the error')
        assert monitor.bad == 1
    finally:
        queue.close()


def test_polled_topics_wake_nobody_and_give_what_came_since(ros):
    """A `PolledTopic`'s messages wait in the reader (no callback runs in the executor) until
    a frame takes them; `LatestIntrinsics` gives the newest valid calibration and counts each
    refused one; `RecentImages` the image of a stamp if it has come, and counts bytes that
    hold no Image."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import CameraInfo, Image

    from pose4d_ros.core.camera import cad60_intrinsics
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.common import close_inputs
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg
    from pose4d_ros.nodes.polled import LatestIntrinsics, RecentImages
    from pose4d_ros.wire import depth_from_msg, stamp_to_ns

    monitor = _Counter()
    refused: list[str] = []
    monitor.bad_input = refused.append
    camera = LatestIntrinsics(ros.node, monitor, topic='polled_test/camera_info')
    depth = RecentImages(ros.node, monitor, 'polled_test/depth', depth_from_msg)
    info_pub = ros.node.create_publisher(CameraInfo, 'polled_test/camera_info', qos.OUTPUT_QOS)
    depth_pub = ros.node.create_publisher(Image, 'polled_test/depth', qos.OUTPUT_QOS)
    try:
        # an executor serves rclpy's subscriptions only: these are not among them
        assert not [s for s in ros.node.subscriptions if 'polled_test' in s.topic_name]
        ros.spin_until(lambda: info_pub.get_subscription_count() > 0
                       and depth_pub.get_subscription_count() > 0, 5.0, 'the readers')
        assert camera.latest() is None and depth.at(0) is None
        intrinsics = cad60_intrinsics()
        info_pub.publish(intrinsics_to_msg(intrinsics, header_at(1)))
        info_pub.publish(serialize_message(intrinsics_to_msg(intrinsics, header_at(2)))[:40])
        metres = np.full((intrinsics.height, intrinsics.width), 2.0, np.float32)
        for k in (1, 2):
            depth_pub.publish(array_to_image(metres * k, '32FC1', header_at(k)))
        depth_pub.publish(b'\x00\x01\x00\x00' + b'\x07' * 20)
        ros.spin_for(0.3)
        assert camera.latest() == intrinsics
        assert depth.at(stamp_to_ns(header_at(2).stamp))[0, 0] == 4.0
        assert depth.at(10 ** 15) is None  # no image of that stamp: not waited for
        assert len(refused) == 2, refused
        assert 'polled_test/camera_info' in refused[0] and 'polled_test/depth' in refused[1]
    finally:
        close_inputs(ros.node)
    assert not ros.node.__dict__.get('polled_topics')
