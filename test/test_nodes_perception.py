"""`foreground`, `detector` and `pipeline` executables over Fast DDS on rendered RGB-D frames."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from harness import check_tf, start
from numpy.testing import assert_array_equal

from pose4d_ros.core.camera import cad60_intrinsics

INTR = cad60_intrinsics()


@pytest.fixture(scope='module')
def frames(request):
    """Three rendered frames of a person in a room (real UTKinect motion when available)."""
    from conftest import SHARED_DATA

    from pose4d_ros.datasets import utkinect
    from pose4d_ros.synth import render as synth
    from pose4d_ros.synth import scene as synth_scene

    rng = np.random.default_rng(3)
    body = synth.random_body(rng)
    scene = synth_scene.random_scene(rng, INTR, occluder_prob=0.0)
    takes = utkinect.list_takes(SHARED_DATA / 'utkinect') if SHARED_DATA.is_dir() else []
    if takes:
        _, joints = utkinect.resample(utkinect.read_take(takes[-1]))
        poses = [utkinect.to_optical(joints[k]) for k in (100, 101, 102)]
    else:  # a standing pose from the renderer's own neutral skeleton
        pytest.skip('needs ../shared/data/utkinect for a real pose')
    out = []
    for k, pose in enumerate(poses):
        pose = synth.retarget(pose, body)
        r = synth.render(pose, body, scene, INTR, rng=np.random.default_rng(k))
        out.append(r)
    return out


def _publish_frame(ros, pubs, r, header):
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg

    color, depth, info = pubs
    color.publish(array_to_image(r.rgb, 'rgb8', header))
    depth.publish(array_to_image(r.depth_mm, '16UC1', header))
    info.publish(intrinsics_to_msg(INTR, header))


@pytest.mark.parametrize('shift', [(0, 0), (6, -2)], ids=['registered', 'depth_beside'])
def test_foreground_node_masks_the_person(ros, frames, tmp_path, shift):
    """The person's mask, colour and depth out of the foreground node; with the camera's depth
    registered off (moved by -shift), `foreground.depth_shift_px` moves it back first."""
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header

    from pose4d_ros.core.registration import shift_image
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import ns_to_stamp
    from pose4d_ros.wire import depth_from_msg, image_to_array

    params = {'foreground.depth_shift_px': list(shift)} if any(shift) else {}
    sent = [r if not any(shift) else replace(r, depth_mm=shift_image(r.depth_mm, -shift[0],
                                                                     -shift[1]))
            for r in frames]
    node = start('foreground', params, log_dir=tmp_path)
    try:
        pubs = (ros.node.create_publisher(Image, 'camera/color/image_raw', qos.OUTPUT_QOS),
                ros.node.create_publisher(Image, 'camera/depth/image_raw', qos.OUTPUT_QOS),
                ros.node.create_publisher(CameraInfo, 'camera/color/camera_info',
                                          qos.OUTPUT_QOS))
        masks = ros.collect(Image, 'pose4d/foreground/mask', qos.OUTPUT_QOS)
        colors = ros.collect(Image, 'pose4d/foreground/color', qos.OUTPUT_QOS)
        depths = ros.collect(Image, 'pose4d/foreground/depth', qos.OUTPUT_QOS)
        for pub in pubs:
            ros.wait_for_subscribers(pub)
        for topic in ('mask', 'color', 'depth'):
            ros.wait_for_publishers(f'pose4d/foreground/{topic}')
        headers = [Header(stamp=ns_to_stamp(10**18 + k * 33_333_334), frame_id='cam')
                   for k in range(len(frames))]
        for r, header in zip(sent, headers, strict=True):
            ros.send_until_answered(lambda r=r, h=header: _publish_frame(ros, pubs, r, h),
                                    lambda h=header: h in [m.header for m in depths],
                                    f'the frame at {header.stamp.nanosec} ns')
            ros.spin_until(lambda h=header: h in [m.header for m in masks] and
                           h in [m.header for m in colors], 5.0, 'its mask and colour')
    finally:
        assert node.stop() == 0, node.output()

    def first(msgs):  # one result per frame (a frame sent twice may come out twice)
        return {m.header.stamp.nanosec: m for m in reversed(msgs)}

    masks, colors, depths = (list(first(m).values())[::-1] for m in (masks, colors, depths))
    assert [m.header for m in masks] == headers == [m.header for m in colors]
    for r, mask_msg, color_msg, depth_msg in zip(frames, masks, colors, depths, strict=True):
        mask = image_to_array(mask_msg) > 127
        iou = (mask & r.mask).sum() / max((mask | r.mask).sum(), 1)
        assert iou > 0.7, iou
        color = image_to_array(color_msg)
        assert (color[~mask] == 0).all()
        depth = depth_from_msg(depth_msg)
        assert depth_msg.encoding == '16UC1' and np.isnan(depth[~mask]).all()
        # the person's depth where the colour image has them: moved back onto it
        inside = mask & r.mask & np.isfinite(depth)
        assert inside.sum() > 0.7 * r.mask.sum()
        assert_array_equal(np.round(depth[inside] * 1000), r.depth_mm[inside])


def _part_errors_px(joints, frame) -> dict[str, float]:
    """Pixel error of each located part against the rendered body's joints."""
    from pose4d_ros.core.camera import project
    from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS

    truth = project(frame.joints, INTR)
    out = {}
    for k, name in enumerate(joints.names):
        gt = UTKINECT_JOINTS.index('shoulder_center' if name == 'neck' else name)
        if np.isfinite(joints.uv[k]).all():
            out[name] = float(np.linalg.norm(joints.uv[k] - truth[gt]))
    return out


def _send_until_answered(ros, pubs, frames, headers, answers, complete=lambda m: True) -> None:
    """Publish each frame until a `complete` answer to it comes out (a detector that has no
    camera_info yet answers with pixels but no 3-D)."""
    for r, header in zip(frames, headers, strict=True):
        ros.send_until_answered(
            lambda r=r, h=header: _publish_frame(ros, pubs, r, h),
            lambda h=header: any(m.header == h and complete(m) for m in answers),
            f'the frame at {header.stamp.nanosec} ns')


def _camera_publishers(ros):
    from sensor_msgs.msg import CameraInfo, Image

    from pose4d_ros.nodes import qos

    return (ros.node.create_publisher(Image, 'camera/color/image_raw', qos.OUTPUT_QOS),
            ros.node.create_publisher(Image, 'camera/depth/image_raw', qos.OUTPUT_QOS),
            ros.node.create_publisher(CameraInfo, 'camera/color/camera_info', qos.OUTPUT_QOS))


@pytest.mark.parametrize('detector_params', [
    {}, {'detector.colour_net': ''},
    {'detector.colour_net_precision': 'fp32', 'detector.colour_net_weight': 0.1}],
    ids=['default', 'hog', 'colour_net_fp32'])
def test_foreground_and_detector_nodes_find_the_parts(ros, frames, tmp_path, detector_params):
    from pose4d_msgs.msg import JointArray
    from std_msgs.msg import Header

    from pose4d_ros.core.skeleton import PARTS_14
    from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import ns_to_stamp
    from pose4d_ros.wire import joints_from_msg

    nodes = [start('foreground', {}, log_dir=tmp_path),
             start('detector', detector_params, log_dir=tmp_path)]
    try:
        pubs = _camera_publishers(ros)
        parts = ros.collect(JointArray, 'pose4d/parts', qos.OUTPUT_QOS)
        for pub in pubs:  # the foreground reads the depth, the detector the colour, both info
            ros.wait_for_subscribers(pub, count=2 if pub.topic_name.endswith('camera_info')
                                     else 1, timeout=30.0)
        ros.wait_for_publishers('pose4d/parts', timeout=30.0)
        headers = [Header(stamp=ns_to_stamp(10**18 + k * 33_333_334), frame_id='cam')
                   for k in range(len(frames))]
        head = PARTS_14.names.index('head')  # the default model's parts
        _send_until_answered(ros, pubs, frames, headers, parts,
                             lambda m: np.isfinite(m.joints[head].position.z))
    finally:
        for node in nodes:
            assert node.stop() == 0, node.output()
    # the network in the part model's colour unary (by default) is said at start-up
    assert ('colour net lspet_convnet)' in nodes[1].output()) == \
        (detector_params.get('detector.colour_net') != '')
    answers = {m.header.stamp.nanosec: m for m in parts
               if np.isfinite(m.joints[head].position.z)}
    assert sorted(answers) == sorted(h.stamp.nanosec for h in headers)
    for r, header in zip(frames, headers, strict=True):
        joints = joints_from_msg(answers[header.stamp.nanosec])
        assert joints.names == PARTS_14.names
        errors = _part_errors_px(joints, r)
        assert len(errors) >= 11 and np.median(list(errors.values())) < 10, errors
        z = joints.xyz[head, 2]
        assert abs(z - r.joints[UTKINECT_JOINTS.index('head'), 2]) < 0.15, z


def test_pipeline_node_publishes_the_skeleton_and_survives_a_bad_frame(ros, frames, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from pose4d_msgs.msg import JointArray
    from std_msgs.msg import Header
    from tf2_msgs.msg import TFMessage

    from pose4d_ros.core.skeleton import SKELETON_14
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg, ns_to_stamp
    from pose4d_ros.wire import joints_from_msg

    node = start('pipeline', {'pipeline.publish_foreground': False}, log_dir=tmp_path)
    try:
        pubs = _camera_publishers(ros)
        skeletons = ros.collect(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        tf = ros.collect(TFMessage, '/tf', qos.TF_QOS)
        diagnostics = ros.collect(DiagnosticArray, '/diagnostics')
        for pub in pubs:
            ros.wait_for_subscribers(pub, timeout=30.0)
        ros.wait_for_publishers('pose4d/skeleton', timeout=30.0)
        ros.wait_for_publishers('/tf')
        headers = [Header(stamp=ns_to_stamp(10**18 + k * 33_333_334), frame_id='cam')
                   for k in range(len(frames))]
        _send_until_answered(ros, pubs, frames[:1], headers[:1], skeletons)
        # a depth image of the wrong size: refused, logged, counted; the node goes on (sent
        # again, at later stamps, until it is refused: best effort may lose a frame)
        color, depth, info = pubs
        for k in range(1, 15):
            bad = Header(stamp=ns_to_stamp(10**18 + k * 1_000_000), frame_id='cam')
            color.publish(array_to_image(frames[1].rgb, 'rgb8', bad))
            depth.publish(array_to_image(frames[1].depth_mm[::2, ::2].copy(), '16UC1', bad))
            info.publish(intrinsics_to_msg(INTR, bad))
            if ros.wait(lambda: 'refused: colour is 320x240 but depth is 160x120'
                        in node.output(), 1.0):
                break
        _send_until_answered(ros, pubs, frames[1:], headers[1:], skeletons)
        ros.spin_until(lambda: any(kv.key == 'bad_inputs' and int(kv.value) >= 1
                                   for d in diagnostics for s in d.status for kv in s.values),
                       5.0, 'the bad frame counted on /diagnostics')
        ros.spin_until(lambda: len(tf) >= len(skeletons), 5.0, 'the joints on /tf')
    finally:
        assert node.stop() == 0, node.output()
    assert check_tf(skeletons, tf) >= len(skeletons)  # the skeletons' joints, on /tf
    answers = {m.header.stamp.nanosec: m for m in skeletons}
    assert sorted(answers) == sorted(h.stamp.nanosec for h in headers)
    for r, header in zip(frames, headers, strict=True):
        skeleton = joints_from_msg(answers[header.stamp.nanosec])
        assert skeleton.names == SKELETON_14
        head = SKELETON_14.index('head')
        assert _part_errors_px(skeleton, r)['head'] < 10
        assert np.isfinite(skeleton.xyz[head]).all()
