"""Simulated time: a bag replayed with /clock runs the graph on the bag's time.

A bag of detected parts at 30 fps, stamped in 2012 (as a recording is), goes through the
`tracker` node. With `replay.publish_clock` and `use_sim_time` the tracker's diagnostics (rate,
latency, the time step of its filter) and the recorder's stamps are the bag's, although the bag
plays at twice its speed; without sim time the tracker says its input comes from another clock
instead of publishing a latency of years.
"""

from __future__ import annotations

import numpy as np
import pytest
from harness import start
from helpers import INTR, parts_msg

from pose4d_ros.datasets import bag

FRAMES = 60
T0_NS = 1_325_419_200_000_000_000  # 2012-01-01 12:00 UTC
STEP_NS = 33_333_333


def _parts_bag(path):
    """60 frames of 10 detected parts (and camera_info), 30 fps, bag time = header stamp."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import intrinsics_to_msg, ns_to_stamp

    with bag.BagWriter(path) as writer:
        writer.add_topic('/camera/color/camera_info', 'sensor_msgs/msg/CameraInfo')
        writer.add_topic('/pose4d/parts', 'pose4d_msgs/msg/JointArray')
        for k in range(FRAMES):
            stamp = T0_NS + k * STEP_NS
            header = Header(stamp=ns_to_stamp(stamp), frame_id='camera_color_optical_frame')
            writer.write('/camera/color/camera_info', stamp,
                         serialize_message(intrinsics_to_msg(INTR, header)))
            writer.write('/pose4d/parts', stamp, serialize_message(parts_msg(k, header)))
    return path


def _last_status(diagnostics, name: str) -> dict[str, str]:
    """The key-values of the last status of `name` that accounted for every frame: processed
    (`frames`) or, came while the worker was busy, dropped and counted (`dropped`: a stage
    works on the newest frame; a cold machine's first frames can be slow)."""
    for array in reversed(diagnostics):
        for status in array.status:
            values = {kv.key: kv.value for kv in status.values}
            if status.name == name and \
                    int(values.get('frames', 0)) + int(values.get('dropped', 0)) == FRAMES:
                return values
    return {}


@pytest.mark.parametrize('sim_time', [True, False])
def test_replay_at_2x_runs_the_graph_on_the_bag_clock(ros, tmp_path, sim_time):
    from diagnostic_msgs.msg import DiagnosticArray

    source = _parts_bag(tmp_path / 'parts')
    recorded = tmp_path / 'tracked'
    clock = {'use_sim_time': sim_time}
    diagnostics = ros.collect(DiagnosticArray, '/diagnostics')
    tracker = start('tracker', clock, log_dir=tmp_path)
    recorder = start('recorder', {**clock, 'recorder.output': str(recorded),
                                  'recorder.topics': ['pose4d/parts/tracked']},
                     log_dir=tmp_path)
    try:
        ros.spin_until(lambda: ros.node.count_subscribers('/pose4d/parts/tracked') >= 1, 30.0,
                       'the recorder on the tracker\'s output')
        replay = start('replay', {'replay.bag': str(source), 'replay.rate': 2.0,
                                  'replay.publish_clock': sim_time, 'replay.delay_s': 0.5,
                                  # with sim time, the tracker's and the recorder's clocks
                                  # too: a recorder that missed every /clock stamps with 0
                                  'replay.wait_for_subscribers': ['pose4d/parts=1'] + (
                                      ['clock=2'] if sim_time else [])},
                       log_dir=tmp_path)
        assert replay.wait(60) == 0, replay.output()
        ros.spin_until(lambda: _last_status(diagnostics, 'pose4d: tracker'), 10.0,
                       f'the tracker counting {FRAMES} frames on /diagnostics')
    finally:
        assert tracker.stop() == 0, tracker.output()
        assert recorder.stop() == 0, recorder.output()
    status = _last_status(diagnostics, 'pose4d: tracker')
    # the filter's time step is the bag's 1/30 s whatever the replay speed
    assert float(status['time_step_ms_p50']) == pytest.approx(STEP_NS * 1e-6, abs=0.01), status
    warnings = tracker.output().count('come from another clock')
    stamps = np.array([m.timestamp_ns for m in bag.read_messages(recorded)])
    assert len(stamps) == int(status['frames']) >= FRAMES - 5, (status, recorder.output())
    if sim_time:
        # rate and latency on the bag's clock: 30 Hz (not the 60 Hz of the wall clock), and
        # a latency of at most a frame or two of bag time
        assert float(status['rate_hz']) == pytest.approx(30.0, rel=0.1), status
        assert abs(float(status['latency_ms_p50'])) < 70.0, status
        assert 'clock_mismatch' not in status and warnings == 0, status
        # the recorder stamps on the bag's clock too
        assert T0_NS <= stamps.min() and stamps.max() <= T0_NS + FRAMES * STEP_NS
    else:
        # stamps from 2012 against today's clock: said once, no absurd latency published
        assert 'clock_mismatch' in status and 'latency_ms_p50' not in status, status
        assert float(status['rate_hz']) > 40.0, status  # the wall clock's (2x the bag's 30 Hz)
        assert warnings == 1, tracker.output()
        assert stamps.min() > T0_NS + 10**17  # wall-clock receive times
