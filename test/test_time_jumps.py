"""Time that jumps: a looping replay on sim time (the clock goes back at each loop) and a
10 s gap in a bag start the tracker and the IK anew (`StageMonitor.time_jumped`).

A bag of detected parts at 30 fps with a 10 s hole in it is replayed twice (`replay.loop`,
`replay.publish_clock`) into `tracker` and `ik` on `use_sim_time`. At each jump (forward over the
hole, back at the loop) the tracker starts a new track on the detections of that frame (no part
predicted from before the jump), the IK follows its track id, and both count the jumps.
"""

from __future__ import annotations

import re

import numpy as np
from harness import start
from helpers import INTR, parts_msg

from pose4d_ros.core import joints as cj
from pose4d_ros.datasets import bag
from pose4d_ros.wire import stamp_to_ns

T0_NS = 1_325_419_200_000_000_000  # 2012-01-01 12:00 UTC
STEP_NS = 33_333_333
GAP_NS = 10 * 10**9
BEFORE, AFTER = 20, 15  # frames before and after the hole


def _stamp(k: int) -> int:
    return T0_NS + k * STEP_NS + (GAP_NS if k >= BEFORE else 0)


def _bag(path):
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import intrinsics_to_msg, ns_to_stamp

    with bag.BagWriter(path) as writer:
        writer.add_topic('/camera/color/camera_info', 'sensor_msgs/msg/CameraInfo')
        writer.add_topic('/pose4d/parts', 'pose4d_msgs/msg/JointArray')
        for k in range(BEFORE + AFTER):
            stamp = _stamp(k)
            header = Header(stamp=ns_to_stamp(stamp), frame_id='camera_color_optical_frame')
            writer.write('/camera/color/camera_info', stamp,
                         serialize_message(intrinsics_to_msg(INTR, header)))
            writer.write('/pose4d/parts', stamp, serialize_message(parts_msg(k, header)))
    return path


def test_a_loop_and_a_gap_start_the_tracker_and_the_ik_anew(ros, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from pose4d_msgs.msg import JointArray

    from pose4d_ros.nodes import qos

    source = _bag(tmp_path / 'parts')
    clock = {'use_sim_time': True}
    tracked = ros.collect(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
    skeletons = ros.collect(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
    diagnostics = ros.collect(DiagnosticArray, '/diagnostics')
    tracker = start('tracker', clock, log_dir=tmp_path)
    ik = start('ik', {**clock, 'ik.use_depth': False}, log_dir=tmp_path)
    replay = None
    try:
        # the ik reads the tracker's several-person output; this test its single-person one
        ros.spin_until(lambda: ros.node.count_subscribers('/pose4d/parts/tracked/people') >= 1
                       and ros.node.count_subscribers('/pose4d/parts') >= 1, 30.0,
                       'the ik on the tracker\'s output, the tracker on the bag\'s')
        replay = start('replay', {'replay.bag': str(source), 'replay.rate': 5.0,
                                  'replay.loop': True, 'replay.publish_clock': True,
                                  'replay.wait_for_subscribers': ['pose4d/parts=1', 'clock=2']},
                       log_dir=tmp_path)
        passes = 2
        ros.spin_until(lambda: len(skeletons) >= passes * (BEFORE + AFTER), 60.0,
                       f'{passes} passes of the bag through the tracker and the ik')
        ros.spin_for(1.5)  # the next /diagnostics
    finally:
        if replay is not None:
            replay.stop()
        assert tracker.stop() == 0, tracker.output()
        assert ik.stop() == 0, ik.output()
    index = {_stamp(k): k for k in range(BEFORE + AFTER)}
    frames = [index[stamp_to_ns(m.header.stamp)] for m in tracked]
    # the frames right after a jump: the first after the hole, the first of each new pass
    jumps = [n for n in range(1, len(frames)) if frames[n] in (0, BEFORE)]
    assert len(jumps) >= 2, frames
    for n in jumps:
        before, after = tracked[n - 1], tracked[n]
        assert after.track_id == before.track_id + 1, (frames[n], before.track_id,
                                                       after.track_id)
        # a new track starts on this frame's detections: nothing predicted from the old one
        detections = parts_msg(frames[n], after.header)
        by_name = {j.name: j for j in detections.joints}
        for joint in after.joints:
            assert joint.source == cj.DETECTED, (frames[n], joint.name, joint.source)
            assert np.allclose((joint.u, joint.v), (by_name[joint.name].u,
                                                    by_name[joint.name].v), atol=1e-3)
    # the IK follows the tracks: each skeleton has its tracked parts' id, in arrival order (the
    # stamps repeat at each pass); an IK slower than the 5x replay drops the older of the frames
    # that came while it was busy, so the skeletons are the tracked frames with some left out
    def ids(msgs):
        return [(stamp_to_ns(m.header.stamp), m.track_id) for m in msgs]

    remaining = iter(ids(tracked))
    assert all(frame in remaining for frame in ids(skeletons)), (ids(skeletons), ids(tracked))
    counts = {}
    for array in diagnostics:
        for status in array.status:
            for kv in status.values:
                if kv.key == 'time_jumps':
                    counts[status.name] = int(kv.value)
    assert counts.get('pose4d: tracker', 0) >= 2 and counts.get('pose4d: ik', 0) >= 2, counts
    # the first jump (throttled): the 10 s hole, a frame or two more where the tracker, busy,
    # dropped the frames that came meanwhile (it drops the oldest, never queues)
    jumped = re.search(r'input stamps jumped forward ([0-9.]+) s', tracker.output())
    assert jumped and 10.0 <= float(jumped.group(1)) <= 10.2, tracker.output()
