"""Managed (lifecycle) nodes: each stage node driven through configure, activate, deactivate,
cleanup and shutdown by a manager, as `ros2 lifecycle set/get` drive it (its services: the ros2
command line is not among the PyPI wheels, `harness.RosPeer.lifecycle_set/get` call what it
calls); an inactive node takes no frame and no CPU while the camera plays; a node started
plainly is active, as before."""

from __future__ import annotations

import time

import numpy as np
import pytest
from harness import cpu_seconds, start
from helpers import INTR, header_at

# each stage node: one of its inputs and one of its outputs
STAGES = {
    'foreground': ('/camera/depth/image_raw', '/pose4d/foreground/mask'),
    'detector': ('/pose4d/foreground/mask', '/pose4d/parts/people'),
    'tracker': ('/pose4d/parts/people', '/pose4d/parts/tracked/people'),
    'ik': ('/pose4d/parts/tracked/people', '/pose4d/skeletons'),
    'pipeline': ('/camera/depth/image_raw', '/pose4d/skeletons'),
}


def _graph_has(ros, count, topic: str, n: int, what: str) -> None:
    ros.spin_until(lambda: count(topic) == n, 10.0, f'{n} {what} on {topic}')


@pytest.mark.parametrize('name', sorted(STAGES))
def test_stage_node_goes_through_its_lifecycle_as_a_manager_drives_it(ros, tmp_path, name):
    """Unconfigured (parameters served, nothing on the graph), configure (its publishers),
    activate (its inputs subscribed), deactivate (unsubscribed), again active, cleanup
    (nothing left), configure again, and shutdown ends the process with status 0. A transition
    that the state does not offer is refused, as ros2cli refuses it."""
    subs, pubs = ros.node.count_subscribers, ros.node.count_publishers
    topic_in, topic_out = STAGES[name]
    node = start(name, {'lifecycle.autostart': False}, log_dir=tmp_path)
    try:
        assert ros.lifecycle_get(name) == 'unconfigured'
        # the parameters are declared at construction: `ros2 param` works unconfigured
        refused = ros.set_parameters(name, {'lifecycle.autostart': True})[0]
        assert not refused.successful and 'read-only' in refused.reason
        assert subs(topic_in) == 0 and pubs(topic_out) == 0
        assert not ros.lifecycle_set(name, 'activate')  # not from unconfigured

        assert ros.lifecycle_set(name, 'configure')
        assert ros.lifecycle_get(name) == 'inactive'
        _graph_has(ros, pubs, topic_out, 1, 'publisher')
        assert subs(topic_in) == 0

        for _ in range(2):  # and once more: what deactivate undid, activate makes anew
            assert ros.lifecycle_set(name, 'activate')
            assert ros.lifecycle_get(name) == 'active'
            _graph_has(ros, subs, topic_in, 1, 'subscriber')
            assert ros.lifecycle_set(name, 'deactivate')
            assert ros.lifecycle_get(name) == 'inactive'
            _graph_has(ros, subs, topic_in, 0, 'subscriber')
            assert pubs(topic_out) == 1  # the publishers stay while inactive

        assert ros.lifecycle_set(name, 'cleanup')
        assert ros.lifecycle_get(name) == 'unconfigured'
        _graph_has(ros, pubs, topic_out, 0, 'publisher')
        assert ros.lifecycle_set(name, 'configure')
        assert ros.lifecycle_get(name) == 'inactive'
        assert ros.lifecycle_set(name, 'shutdown')
        assert node.wait(15.0) == 0, node.output()
    finally:
        node.kill()
    log = node.log_path.read_text()
    for step in ('configure', 'activate', 'deactivate', 'cleanup', 'shutdown'):
        assert f'lifecycle: {step} done' in log, log


def test_a_node_started_plainly_is_active(ros, tmp_path):
    node = start('tracker', {}, log_dir=tmp_path)
    try:
        assert ros.lifecycle_get('tracker') == 'active'
        ros.spin_until(lambda: ros.node.count_subscribers('/pose4d/parts/people') == 1, 10.0,
                       'the tracker subscribed')
    finally:
        assert node.stop() == 0, node.output()
    assert 'lifecycle:' not in node.output()  # as before: no word of the lifecycle


def test_a_model_that_does_not_load_fails_configure_and_the_node_stays_unconfigured(
        ros, tmp_path):
    model = tmp_path / 'broken.npz'
    model.write_bytes(b'not a model')
    node = start('detector', {'lifecycle.autostart': False, 'detector.model': str(model)},
                 log_dir=tmp_path)
    try:
        assert not ros.lifecycle_set('detector', 'configure')
        assert ros.lifecycle_get('detector') == 'unconfigured'
    finally:
        assert node.stop() == 0, node.output()
    assert 'configure failed: parameter detector.model' in node.output()


def _camera(ros):
    """Publishers of the foreground's inputs and a function that sends frame k: a wall 4 m
    away with a box 2.5 m away (320x240 depth, 16UC1) and the colour camera_info."""
    from sensor_msgs.msg import CameraInfo, Image

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg

    depth_pub = ros.node.create_publisher(Image, 'camera/depth/image_raw', qos.SENSOR_QOS)
    info_pub = ros.node.create_publisher(CameraInfo, 'camera/color/camera_info',
                                         qos.SENSOR_QOS)
    depth = np.full((INTR.height, INTR.width), 4000, np.uint16)
    depth[60:220, 140:190] = 2500

    def send(k: int) -> None:
        header = header_at(k)
        info_pub.publish(intrinsics_to_msg(INTR, header))
        depth_pub.publish(array_to_image(depth, '16UC1', header))

    return send


def _play(ros, send, first: int, seconds: float, pid: int) -> tuple[float, int]:
    """Send frames at 30 Hz for `seconds`; the CPU seconds process `pid` used meanwhile and the
    number of frames sent."""
    cpu = cpu_seconds(pid)
    t0 = time.monotonic()
    k = first
    while time.monotonic() - t0 < seconds:
        send(k)
        k += 1
        ros.spin_for(max(0.0, t0 + (k - first) / 30 - time.monotonic()))
    return cpu_seconds(pid) - cpu, k - first


def test_an_inactive_node_takes_no_frame_and_no_cpu_while_the_camera_plays(ros, tmp_path):
    """The foreground at 30 Hz: active it masks the frames, inactive it gets none (nothing on
    its outputs, nor diagnostics) and its process uses next to no CPU; active again it serves
    the frames as before."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Image

    from pose4d_ros.nodes import qos
    from pose4d_ros.wire import stamp_to_ns

    node = start('foreground', {'lifecycle.autostart': False}, log_dir=tmp_path)
    try:
        masks = ros.collect(Image, 'pose4d/foreground/mask', qos.OUTPUT_QOS)
        diagnostics = ros.collect(DiagnosticArray, '/diagnostics', 10)
        send = _camera(ros)
        assert ros.lifecycle_set('foreground', 'configure')
        assert ros.lifecycle_set('foreground', 'activate')
        ros.spin_until(lambda: ros.node.count_subscribers('/camera/depth/image_raw') == 1,
                       10.0, 'the foreground subscribed')
        ros.send_until_answered(lambda: send(0), lambda: bool(masks), 'the first frame')

        def ours() -> int:
            return sum(s.name == 'pose4d: foreground' for m in diagnostics for s in m.status)

        seconds = 4.0
        active_cpu, sent = _play(ros, send, 1, seconds, node.proc.pid)
        served = len(masks)
        assert served > 0.8 * sent, (served, sent)

        assert ros.lifecycle_set('foreground', 'deactivate')
        ros.spin_until(lambda: ros.node.count_subscribers('/camera/depth/image_raw') == 0,
                       10.0, 'the foreground unsubscribed')
        ros.spin_for(0.5)  # the frame in hand, the last diagnostics
        before, reports = len(masks), ours()
        inactive_cpu, _ = _play(ros, send, 1000, seconds, node.proc.pid)
        assert len(masks) == before and ours() == reports  # no frame taken, nothing said

        assert ros.lifecycle_set('foreground', 'activate')
        ros.spin_until(lambda: ros.node.count_subscribers('/camera/depth/image_raw') == 1,
                       10.0, 'the foreground subscribed again')
        ros.send_until_answered(lambda: send(2000), lambda: len(masks) > before,
                                'a frame after reactivation')
        _play(ros, send, 2001, 1.5, node.proc.pid)
        assert stamp_to_ns(masks[-1].header.stamp) >= stamp_to_ns(header_at(2001).stamp)
        ros.spin_until(lambda: ours() > reports, 3.0, 'diagnostics again')
    finally:
        assert node.stop() == 0, node.output()
    print(f'foreground CPU over {seconds:.0f} s of 30 Hz 320x240 depth: active '
          f'{active_cpu:.2f} s ({active_cpu / seconds:.1%}), inactive {inactive_cpu:.2f} s '
          f'({inactive_cpu / seconds:.1%})')
    assert inactive_cpu < 0.15 * active_cpu and inactive_cpu / seconds < 0.03, \
        (active_cpu, inactive_cpu)
