"""Tuning live: parameters set while a node runs, through its parameter service.

Live parameters are validated by the same rules as at start-up and take effect from the next
message; the others are read-only and their description says why.
"""

from __future__ import annotations

import numpy as np
import pytest
from harness import start
from helpers import BODY, INTR, header_at, parts_msg

from pose4d_ros.core import joints as cj
from pose4d_ros.core.skeleton import PARTS_10
from pose4d_ros.nodes import detector, foreground, ik, pipeline, recorder, replay, tracker

NODES = {'foreground': foreground, 'detector': detector, 'tracker': tracker, 'ik': ik,
         'pipeline': pipeline, 'replay': replay, 'recorder': recorder}


def test_set_parameters_through_the_service_take_effect_on_the_next_frame(ros, tmp_path):
    from pose4d_msgs.msg import JointArray
    from rcl_interfaces.srv import DescribeParameters
    from sensor_msgs.msg import CameraInfo
    from tf2_msgs.msg import TFMessage

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import intrinsics_to_msg
    from pose4d_ros.wire import stamp_to_ns

    # hri.publish off: the REP 155 body frames go on /tf whatever tf.publish says
    node = start('ik', {'ik.use_depth': False, 'hri.publish': False}, log_dir=tmp_path)
    try:
        info = ros.node.create_publisher(CameraInfo, 'camera/color/camera_info', qos.OUTPUT_QOS)
        pub = ros.node.create_publisher(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
        got = ros.collect(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        tf = ros.collect(TFMessage, '/tf', qos.TF_QOS)
        ros.wait_for_subscribers(pub)
        ros.wait_for_subscribers(info)
        ros.wait_for_publishers('/tf')
        k = 0

        def frames_on_tf(stamp: int) -> set[str]:
            return {t.child_frame_id for m in tf for t in m.transforms
                    if stamp_to_ns(t.header.stamp) == stamp}

        def frame() -> int:
            """Send one frame; wait for its skeleton, and up to 2 s for its joints on /tf."""
            nonlocal k
            header = header_at(k)
            k += 1
            def send() -> None:
                info.publish(intrinsics_to_msg(INTR, header))
                ros.spin_for(0.05)
                pub.publish(parts_msg(0, header))

            # the ik's input is best effort: a frame sent before its reader matched is gone
            ros.send_until_answered(send, lambda: any(m.header == header for m in got),
                                    'the skeleton')
            stamp = stamp_to_ns(header.stamp)
            ros.wait(lambda: frames_on_tf(stamp), 2.0)
            return stamp

        first = frame()
        assert 'pose4d/0/head' in frames_on_tf(first)
        ok = ros.set_parameters('ik', {'tf.prefix': 'people'})
        assert ok[0].successful, ok[0].reason
        assert 'people/0/head' in frames_on_tf(frame())
        assert ros.set_parameters('ik', {'tf.publish': False})[0].successful
        assert frames_on_tf(frame()) == set()
        assert ros.set_parameters('ik', {'tf.publish': True})[0].successful
        assert 'people/0/head' in frames_on_tf(frame())

        # refused: a read-only parameter, a value breaking a rule, one out of range
        refused = ros.set_parameters('ik', {'ik.use_depth': True})[0]
        assert not refused.successful and 'read-only' in refused.reason
        refused = ros.set_parameters('ik', {'tf.prefix': '/people'})[0]
        assert not refused.successful and 'no leading or trailing /' in refused.reason
        refused = ros.set_parameters('ik', {'ik.upper_arm_length_m': 5.0})[0]
        assert not refused.successful
        assert 'people/0/head' in frames_on_tf(frame())  # nothing of that was taken

        described = ros.call(DescribeParameters, '/ik/describe_parameters',
                             DescribeParameters.Request(names=['ik.use_depth', 'tf.publish']))
        use_depth, tf_publish = described.descriptors
        assert use_depth.read_only and 'Read-only while running: it decides at start-up' \
            in use_depth.description
        assert not tf_publish.read_only and 'Settable while running' in tf_publish.description
    finally:
        assert node.stop() == 0, node.output()


@pytest.mark.parametrize('name', sorted(NODES))
def test_every_parameter_is_live_or_says_why_not(name):
    for p in NODES[name].PARAMS:
        d = p.descriptor()
        assert d.read_only == (not p.live)
        assert ('Read-only while running: ' + p.restart) in d.description if not p.live \
            else 'Settable while running' in d.description


def test_values_that_break_a_stage_rule_together_are_refused(ros):
    """depth_near_m and depth_far_m are each in range, but near must stay below far."""
    import rclpy
    from rclpy.parameter import Parameter

    from pose4d_ros.nodes.params import NodeParams

    node = rclpy.create_node('params_probe', context=ros.context)
    try:
        params = NodeParams(node, foreground.PARAMS, check=foreground.foreground_settings)
        result = node.set_parameters([Parameter('foreground.depth_far_m', value=0.3)])[0]
        assert not result.successful and 'depth_near_m < depth_far_m' in result.reason
        assert params.changes() is None and params.values['foreground.depth_far_m'] == 4.5
        result = node.set_parameters([Parameter('foreground.depth_far_m', value=6.0)])[0]
        assert result.successful
        assert params.changes()['foreground.depth_far_m'] == 6.0
        assert params.changes() is None  # reported once
    finally:
        node.destroy_node()


def test_tracker_settings_change_between_frames_and_the_track_goes_on():
    """max_missed_frames from 30 to 0: a part the detector misses is dropped on the next frame
    instead of predicted, and the track keeps its id."""
    from pose4d_ros.core.camera import project
    from pose4d_ros.core.joints import JointSet

    p = {q.name: q.default for q in tracker.PARAMS}
    stage = tracker.tracker_stage(p)
    xyz = np.array([BODY[n] for n in PARTS_10.names])
    wrist = PARTS_10.index('left_wrist')

    def parts(k: int, *, missing: bool = False) -> JointSet:
        uv = project(xyz + [0.002 * k, 0, 0], INTR)
        src = np.full(10, cj.DETECTED, np.uint8)
        if missing:
            uv[wrist], src[wrist] = np.nan, cj.MISSING
        return JointSet(PARTS_10.names, uv, xyz, source=src, confidence=np.full(10, 0.9))

    for k in range(5):
        stage.step(parts(k), k / 30, INTR)
    assert stage.step(parts(5, missing=True), 5 / 30, INTR).source[wrist] == cj.TRACKED
    stage.configure(**tracker.tracker_settings({**p, 'tracker.max_missed_frames': 0}))
    out = stage.step(parts(6, missing=True), 6 / 30, INTR)
    assert out.source[wrist] == cj.MISSING and out.track_id == 1
