"""`tracker` and `ik` executables over Fast DDS: content, header stamp and frame."""

from __future__ import annotations

import time

import numpy as np
import pytest
from harness import check_tf, start
from helpers import INTR, diagnostic_values, header_at, parts_msg

from pose4d_ros.core import joints as cj
from pose4d_ros.core.skeleton import PARTS_10, SKELETON_14


@pytest.fixture
def info_pub(ros):
    from sensor_msgs.msg import CameraInfo

    from pose4d_ros.nodes import qos

    return ros.node.create_publisher(CameraInfo, 'camera/color/camera_info', qos.OUTPUT_QOS)


def test_tracker_node(ros, info_pub, tmp_path):
    from pose4d_msgs.msg import JointArray

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import intrinsics_to_msg
    from pose4d_ros.wire import joints_from_msg

    node = start('tracker', {'tracker.kind': 'slqe'}, log_dir=tmp_path)
    try:
        pub = ros.node.create_publisher(JointArray, 'pose4d/parts', qos.OUTPUT_QOS)
        got = ros.collect(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
        ros.wait_for_subscribers(pub)
        ros.wait_for_subscribers(info_pub)
        ros.wait_for_publishers('pose4d/parts/tracked')
        sent = [header_at(k) for k in range(-1, 20)]

        def send(k: int) -> None:
            info_pub.publish(intrinsics_to_msg(INTR, sent[k + 1]))
            pub.publish(parts_msg(k, sent[k + 1], missing=('left_wrist',) if k == 19 else ()))

        # frame -1 again until the answer has 3-D: the camera is known (best effort may lose
        # camera_info); then each frame once its predecessor is answered
        ros.send_until_answered(lambda: send(-1), lambda: any(
            np.isfinite(joints_from_msg(m).xyz).all() for m in got), 'the first frame')
        for k in range(20):
            send(k)
            ros.spin_until(lambda h=sent[k + 1]: any(m.header == h for m in got), 10,
                           f'frame {k} tracked')
    finally:
        assert node.stop() == 0, node.output()
    assert [m.header for m in got if m.header != sent[0]] == sent[1:]
    last = joints_from_msg(got[-1])
    assert last.names == PARTS_10.names and last.track_id == 1
    i = PARTS_10.index('left_wrist')
    assert last.source[i] == cj.TRACKED and np.isfinite(last.xyz[i]).all()
    assert (last.source[np.arange(10) != i] == cj.DETECTED).all()


@pytest.mark.parametrize('shift', [0, 80], ids=['registered', 'depth_beside'])
def test_tracker_node_ends_the_track_of_a_person_the_depth_sees_through(ros, info_pub,
                                                                         tmp_path, shift):
    """Ten frames of a person, then one without their parts: with the camera's depth showing
    a wall 2.5 m behind where they were, the tracker publishes nobody (the track ended,
    `core.people.free_space`); the depth image of the frame before still showed them. With
    the camera's depth lying `shift` px left of its colour (the person's depth clear of where
    their parts are), `tracker.depth_shift_px` moves it back before it is read."""
    from pose4d_msgs.msg import JointArray
    from sensor_msgs.msg import Image

    from pose4d_ros.core.registration import shift_image
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg
    from pose4d_ros.wire import joints_from_msg

    node = start('tracker', {'tracker.depth_shift_px': [shift, 0]} if shift else {},
                 log_dir=tmp_path)
    try:
        pub = ros.node.create_publisher(JointArray, 'pose4d/parts', qos.OUTPUT_QOS)
        depth_pub = ros.node.create_publisher(Image, 'camera/depth/image_raw', qos.OUTPUT_QOS)
        got = ros.collect(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
        for p in (pub, info_pub, depth_pub):
            ros.wait_for_subscribers(p)
        ros.wait_for_publishers('pose4d/parts/tracked')
        sent = [header_at(k) for k in range(12)]
        person = np.full((INTR.height, INTR.width), 5000, np.uint16)
        person[40:230, 120:200] = 2500  # the person 2.5 m away, a wall at 5 m
        person = shift_image(person, -shift, 0)
        wall = np.full((INTR.height, INTR.width), 5000, np.uint16)

        def send(k: int, depth: np.ndarray, missing=()) -> None:
            info_pub.publish(intrinsics_to_msg(INTR, sent[k]))
            depth_pub.publish(array_to_image(depth, '16UC1', sent[k]))
            time.sleep(0.05)  # the depth first: the tracker never waits for it
            pub.publish(parts_msg(k, sent[k], missing=missing))

        ros.send_until_answered(lambda: send(0, person), lambda: any(
            np.isfinite(joints_from_msg(m).xyz).all() for m in got), 'the first frame')
        for k in range(1, 12):
            send(k, person if k < 11 else wall, missing=PARTS_10.names if k >= 10 else ())
            ros.spin_until(lambda h=sent[k]: any(m.header == h for m in got), 10,
                           f'frame {k} tracked')
    finally:
        assert node.stop() == 0, node.output()
    by_stamp = {(m.header.stamp.sec, m.header.stamp.nanosec): joints_from_msg(m) for m in got}
    at = [by_stamp[(h.stamp.sec, h.stamp.nanosec)] for h in sent]
    assert at[9].track_id == 1 and (at[9].source == cj.DETECTED).all()
    # unseen, the depth still showing them: predicted
    assert at[10].track_id == 1 and (at[10].source == cj.TRACKED).all()
    # unseen, the depth reading the wall where they were: nobody
    assert at[11].track_id == 0 and (at[11].source == cj.MISSING).all()


@pytest.mark.parametrize('use_depth', [False, True])
def test_ik_node(ros, info_pub, tmp_path, use_depth):
    """The skeleton, its markers, and its joints on /tf (read back and checked against the
    skeleton message; the last frame lacks a wrist, so its elbow cannot be inferred either)."""
    from pose4d_msgs.msg import JointArray
    from sensor_msgs.msg import Image
    from tf2_msgs.msg import TFMessage
    from visualization_msgs.msg import MarkerArray

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg
    from pose4d_ros.wire import joints_from_msg

    prefix = 'people' if use_depth else 'pose4d'  # a prefix of our choice, and the default
    node = start('ik', {'ik.use_depth': use_depth, 'tf.prefix': prefix} if use_depth
                 else {'ik.use_depth': use_depth}, log_dir=tmp_path)
    try:
        pub = ros.node.create_publisher(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
        depth_pub = ros.node.create_publisher(Image, 'pose4d/foreground/depth', qos.OUTPUT_QOS)
        got = ros.collect(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        markers = ros.collect(MarkerArray, 'pose4d/skeleton/markers', qos.OUTPUT_QOS)
        tf = ros.collect(TFMessage, '/tf', qos.TF_QOS)
        ros.wait_for_subscribers(pub)
        ros.wait_for_subscribers(info_pub)
        if use_depth:
            ros.wait_for_subscribers(depth_pub)
        ros.wait_for_publishers('pose4d/skeleton')
        ros.wait_for_publishers('/tf')
        depth = np.full((INTR.height, INTR.width), 2500, np.uint16)
        headers = [header_at(k) for k in range(5)]
        elbow = SKELETON_14.index('right_elbow')  # inferred in every frame

        def send(k: int) -> None:
            info_pub.publish(intrinsics_to_msg(INTR, headers[k]))
            pub.publish(parts_msg(0, headers[k], missing=('left_wrist',) if k == 4 else ()))
            if use_depth:
                depth_pub.publish(array_to_image(depth, '16UC1', headers[k]))

        # each frame until answered (best effort may lose camera_info or depth), with pixels
        # for the inferred elbow, which need the camera; then its markers and transforms
        for k, header in enumerate(headers):
            ros.send_until_answered(lambda k=k: send(k), lambda h=header: any(
                m.header == h and np.isfinite(m.joints[elbow].u) for m in got),
                f'the frame at {header.stamp.nanosec} ns')
            ros.spin_until(lambda h=header: any(m.markers[0].header == h for m in markers) and
                           any(m.transforms[0].header == h for m in tf), 5,
                           'its markers and transforms')
    finally:
        assert node.stop() == 0, node.output()
    # one answer per frame (a frame sent again may be answered twice)
    got = list({m.header.stamp.nanosec: m for m in got}.values())
    markers = list({m.markers[0].header.stamp.nanosec: m for m in markers}.values())
    assert [m.header for m in got] == headers
    assert check_tf(got, tf, prefix) == 4 * 14 + 12
    assert {t.child_frame_id for t in tf[0].transforms if not t.child_frame_id.endswith(
        f'_b{got[0].track_id}')} == {  # beside the REP 155 body frames (test_hri.py)
        f'{prefix}/{got[0].track_id}/{name}' for name in SKELETON_14}
    skeleton = joints_from_msg(got[-2])
    assert skeleton.names == SKELETON_14
    for name in ('left_elbow', 'right_elbow', 'left_knee', 'right_knee'):
        i = SKELETON_14.index(name)
        assert skeleton.source[i] == cj.INFERRED and np.isfinite(skeleton.xyz[i]).all()
    assert markers[-1].markers[0].header == headers[-1]
    assert len(markers[-2].markers[0].points) == 14
    assert len(markers[-1].markers[0].points) == 12


def test_ik_node_before_any_camera_info(ros, tmp_path):
    """Frames that come before the camera's first camera_info (its reader may match after the
    others') are completed from the limb prior, not refused: every one is answered with its
    elbows and knees, and none is counted as a bad input."""
    from diagnostic_msgs.msg import DiagnosticArray
    from pose4d_msgs.msg import JointArray
    from sensor_msgs.msg import Image

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image
    from pose4d_ros.wire import joints_from_msg

    diagnostics = ros.collect(DiagnosticArray, '/diagnostics')
    node = start('ik', {'ik.use_depth': True}, log_dir=tmp_path)
    try:
        pub = ros.node.create_publisher(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
        depth_pub = ros.node.create_publisher(Image, 'pose4d/foreground/depth', qos.OUTPUT_QOS)
        got = ros.collect(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        ros.wait_for_subscribers(pub)
        ros.wait_for_subscribers(depth_pub)
        ros.wait_for_publishers('pose4d/skeleton')
        depth = np.full((INTR.height, INTR.width), 2500, np.uint16)
        headers = [header_at(k) for k in range(3)]
        for k, header in enumerate(headers):
            def send(k=k, header=header) -> None:
                pub.publish(parts_msg(0, header))
                depth_pub.publish(array_to_image(depth, '16UC1', header))

            ros.send_until_answered(send, lambda h=header: any(m.header == h for m in got),
                                    f'the frame at {header.stamp.nanosec} ns')
        ros.spin_for(1.5)  # the next /diagnostics
    finally:
        assert node.stop() == 0, node.output()
    skeleton = joints_from_msg(got[-1])
    for name in ('left_elbow', 'right_elbow', 'left_knee', 'right_knee'):
        i = SKELETON_14.index(name)
        assert skeleton.source[i] == cj.INFERRED and np.isfinite(skeleton.xyz[i]).all()
    counts = diagnostic_values(diagnostics, 'ik', 'bad_inputs')
    assert counts and counts[-1] == 0, counts[-1:]
    assert 'camera_info yet' in node.output()


def test_a_signal_racing_the_executor_is_a_clean_exit():
    """A SIGINT that shuts the context down while the executor builds its next wait set makes
    rclpy raise RCLError ('the given context is not valid'), not ExternalShutdownException
    (ros2/rclpy#398): after a shutdown `run` exits 0; the same error on a live context is a
    real failure and propagates."""
    import rclpy
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    from rclpy.node import Node

    from pose4d_ros.nodes.common import run

    def after_shutdown(node):
        rclpy.try_shutdown()    # what the signal handler does
        raise _rclpy.RCLError('failed to initialize wait set: the given context is not valid')

    def while_alive(node):
        raise _rclpy.RCLError('failed to initialize wait set: something else')

    assert run(lambda: Node('racing'), [], after_shutdown) == 0
    with pytest.raises(RuntimeError, match='something else'):
        run(lambda: Node('racing'), [], while_alive)
    assert not rclpy.ok()
