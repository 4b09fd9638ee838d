"""ROS4HRI (REP 155) bodies: the mapping of our joints onto hri_msgs' Skeleton2D, the region of
interest and the body frames (`core.hri`), their bytes against rclpy's serialisation
(`wire.hri`), and the `ik` node publishing them through DDS for two people: the ids on
/humans/bodies/tracked, each body's skeleton2d and roi, its frames on /tf, and its publishers
gone once it has left."""

from __future__ import annotations

import math

import numpy as np
import pytest
from harness import start
from helpers import INTR, header_at, parts_msg

from pose4d_ros.core import hri
from pose4d_ros.core.camera import project
from pose4d_ros.core.joints import DETECTED, MISSING, JointSet
from pose4d_ros.core.skeleton import SKELETON_14

W, H = 640, 480


def person(rng: np.random.Generator | None = None, *, turn_deg: float = 0.0,
           missing: tuple[str, ...] = ()) -> JointSet:
    """A standing person 3 m in front of the camera (optical frame: x right, y down, z away),
    facing it, turned `turn_deg` about the vertical; pixels of a 640x480 camera."""
    x = {'head': (0, -0.75), 'neck': (0, -0.55), 'shoulder': (0.2, -0.5),
         'elbow': (0.25, -0.25), 'wrist': (0.27, 0.0), 'hip': (0.12, 0.0),
         'knee': (0.13, 0.45), 'ankle': (0.13, 0.85)}
    xyz = []
    for name in SKELETON_14:
        side, _, part = name.rpartition('_')
        dx, y = x[part] if side else x[name]
        # the person's left is the camera's right when they face it
        xyz.append(((dx if side == 'left' else -dx), y, 0.0))
    xyz = np.array(xyz, float)
    a = math.radians(turn_deg)
    xyz = xyz @ np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0],
                          [math.sin(a), 0, math.cos(a)]]).T + [0.1, 0.0, 3.0]
    if rng is not None:
        xyz += rng.normal(0, 0.01, xyz.shape)
    uv = xyz[:, :2] / xyz[:, 2:] * 570.0 + [320.0, 240.0]
    src = np.full(14, DETECTED, np.uint8)
    conf = np.linspace(0.3, 0.95, 14).astype(np.float32)
    for name in missing:
        i = SKELETON_14.index(name)
        src[i], conf[i] = MISSING, 0.0
        uv[i] = np.nan
    return JointSet(SKELETON_14, uv, xyz, confidence=conf, source=src, track_id=7)


def test_skeleton2d_maps_our_joints_onto_coco_keypoints():
    joints = person(missing=('left_knee',))
    points = hri.skeleton2d(joints, W, H)
    assert points.shape == (18, 3) and points.dtype == np.float32
    codes = {name: k for k, name in enumerate(hri.SKELETON2D_KEYPOINTS)}
    for name, k in codes.items():
        i = joints.get(name)
        if i is None or name == 'left_knee':  # none of ours, or MISSING: confidence 0
            assert tuple(points[k]) == (0, 0, 0), name
            continue
        u, v = joints.uv[i]
        np.testing.assert_allclose(points[k], [(u + 0.5) / W, (v + 0.5) / H,
                                               joints.confidence[i]], rtol=1e-6)
    # the message's constants (hri_msgs/Skeleton2D): left and right are the person's own
    assert (codes['nose'], codes['neck'], codes['right_wrist'], codes['left_ankle'],
            codes['right_ear']) == (0, 1, 4, 13, 17)
    # the person faces the camera: their right side is on the image's left
    assert points[codes['right_shoulder'], 0] < points[codes['left_shoulder'], 0]


def test_skeleton2d_clips_to_the_image_and_refuses_no_size():
    joints = person().with_(uv=person().uv + [-2000.0, 3000.0])
    points = hri.skeleton2d(joints, W, H)
    assert (points[1:14, 0] == 0).all() and (points[1:14, 1] == 1).all()
    with pytest.raises(ValueError, match='0x480'):
        hri.skeleton2d(joints, 0, H)


def test_roi_is_the_joints_box_grown_by_its_margin():
    joints = person(missing=('head',))
    xmin, ymin, xmax, ymax, c = hri.body_roi(joints, W, H)
    uv = joints.uv[joints.source != MISSING] + 0.5
    grow = hri.ROI_MARGIN * (uv[:, 1].max() - uv[:, 1].min())
    np.testing.assert_allclose([xmin * W, ymin * H, xmax * W, ymax * H],
                               [uv[:, 0].min() - grow, uv[:, 1].min() - grow,
                                uv[:, 0].max() + grow, uv[:, 1].max() + grow], atol=1e-9)
    assert c == pytest.approx(joints.confidence[joints.source != MISSING].mean())
    assert hri.body_roi(JointSet.missing(SKELETON_14), W, H) is None
    edge = hri.body_roi(person().with_(uv=person().uv + [300.0, 200.0]), W, H)
    assert 0 <= edge[0] < edge[2] == 1 and 0 <= edge[1] < edge[3] == 1


@pytest.mark.parametrize('turn', [0.0, 35.0, -120.0])
def test_body_frames_follow_rep_155(turn):
    """body_<id> at the hips' middle, x forward (towards the camera for a person facing it),
    y to the person's left, z up; every located joint's link in it, composing back to the
    joint's position."""
    joints = person(np.random.default_rng(0), turn_deg=turn, missing=('left_wrist',))
    rows = hri.body_transforms(joints, 'camera_color_optical_frame', 'b7')
    parent, child, pose = rows[0]
    assert (parent, child) == ('camera_color_optical_frame', 'body_b7')
    origin, q = np.array(pose[:3]), np.array(pose[3:])
    mid = 0.5 * (joints.xyz[joints.index('left_hip')] + joints.xyz[joints.index('right_hip')])
    np.testing.assert_allclose(origin, mid, atol=1e-12)
    r = _matrix(q)
    a = math.radians(turn)
    forward = np.array([math.sin(a), 0.0, -math.cos(a)])  # facing the camera, then turned
    assert r[:, 0] @ forward > 0.98 and r[:, 2] @ [0, -1, 0] > 0.98
    assert r[:, 1] @ np.cross(r[:, 2], r[:, 0]) > 0.999  # right-handed: y = z x x
    names = {c: p for p, c, _ in rows[1:]}
    assert set(names.values()) == {'body_b7'}
    expected = {f'{link}_b7' for name, link in hri.BODY_LINKS.items() if name != 'left_wrist'}
    assert set(names) == expected and 'l_wrist_b7' not in names
    for _, child, pose in rows[1:]:
        name = next(n for n, link in hri.BODY_LINKS.items() if child == f'{link}_b7')
        np.testing.assert_allclose(r @ pose[:3] + origin, joints.xyz[joints.index(name)],
                                   atol=1e-9)
        assert pose[3:] == (0.0, 0.0, 0.0, 1.0)


def test_no_body_frames_without_both_hips():
    assert hri.body_transforms(person(missing=('right_hip',)), 'cam', 'b1') == []


def test_quaternion_of_random_rotations():
    from scipy.spatial.transform import Rotation

    for r in Rotation.random(200, random_state=0):
        q = np.array(hri.quaternion(r.as_matrix()))
        want = r.as_quat()
        want = want if want[3] >= 0 else -want
        np.testing.assert_allclose(q, want, atol=1e-12)


def test_body_ids_and_their_prefix():
    assert hri.body_id(12) == 'b12' and hri.body_id(3, 'p4d') == 'p4d3'
    assert hri.id_prefix_problem('b') is None and hri.id_prefix_problem('body2') is None
    for bad in ('', '1', 'b_', 'a/b', 'b d'):
        assert hri.id_prefix_problem(bad), bad


def _matrix(q) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).as_matrix()


def test_bytes_read_back_as_the_messages():
    """Our bytes deserialise (rclpy) to the message built from the same values; the same
    length as rclpy's serialisation (whose padding bytes are not always zero)."""
    from geometry_msgs.msg import TransformStamped
    from hri_msgs.msg import (
        IdsList,
        NormalizedPointOfInterest2D,
        NormalizedRegionOfInterest2D,
        Skeleton2D,
    )
    from rclpy.serialization import deserialize_message, serialize_message
    from tf2_msgs.msg import TFMessage

    from pose4d_ros.wire import ids_list_to_cdr, roi_to_cdr, skeleton2d_to_cdr, tf_to_cdr

    header = header_at(3)
    joints = person()
    def same(data: bytes, msg) -> bool:
        return (deserialize_message(data, type(msg)) == msg
                and len(data) == len(serialize_message(msg)))

    for ids in ([], ['b1'], ['b1', 'b22', 'b333']):
        assert same(ids_list_to_cdr(ids, header), IdsList(header=header, ids=ids))
    points = hri.skeleton2d(joints, W, H)
    msg = Skeleton2D(header=header, skeleton=[
        NormalizedPointOfInterest2D(x=float(x), y=float(y), c=float(c)) for x, y, c in points])
    assert same(skeleton2d_to_cdr(points, header), msg)
    roi = hri.body_roi(joints, W, H)
    msg = NormalizedRegionOfInterest2D(header=header, **dict(zip(
        ('xmin', 'ymin', 'xmax', 'ymax', 'c'), (float(np.float32(v)) for v in roi),
        strict=True)))
    assert same(roi_to_cdr(roi, header), msg)
    rows = hri.body_transforms(joints, header.frame_id, 'b7')
    msg = TFMessage()
    for parent, child, pose in rows:
        t = TransformStamped(child_frame_id=child)
        t.header.stamp, t.header.frame_id = header.stamp, parent
        tr, rot = t.transform.translation, t.transform.rotation
        tr.x, tr.y, tr.z, rot.x, rot.y, rot.z, rot.w = pose
        msg.transforms.append(t)
    assert same(tf_to_cdr([], header, 'pose4d', rows), msg)
    assert tf_to_cdr([], header, 'pose4d') is None


def _two_people(k: int, header):
    """Person 1 as `helpers.parts_msg` puts them, person 2 the same 0.8 m to their right
    (camera's left) and 0.5 m farther, as a SkeletonArray of tracks 1 and 2."""
    from pose4d_msgs.msg import SkeletonArray

    first = parts_msg(k, header)
    first.track_id = 1
    second = parts_msg(k, header)
    second.track_id = 2
    for j in second.joints:
        j.position.x -= 0.8
        j.position.z += 0.5
        j.u, j.v = (float(c) for c in project(np.array([[j.position.x, j.position.y,
                                                         j.position.z]]), INTR)[0])
    return SkeletonArray(header=header, skeletons=[first, second])


def test_ik_node_publishes_rep155_bodies(ros, tmp_path):
    """Two tracked people into the `ik` node; out: /humans/bodies/tracked = [b1, b2] for every
    frame, each body's skeleton2d (our pixels normalised, on the skeleton of the same stamp)
    and roi, its frames on /tf beside the joints'; then nobody, and once hri.forget_after_s
    of stamps have passed, the bodies' publishers are gone."""
    from hri_msgs.msg import IdsList, NormalizedRegionOfInterest2D, Skeleton2D
    from pose4d_msgs.msg import SkeletonArray
    from sensor_msgs.msg import CameraInfo
    from tf2_msgs.msg import TFMessage

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import intrinsics_to_msg
    from pose4d_ros.wire import skeletons_from_msg, stamp_to_ns

    node = start('ik', {'ik.use_depth': False, 'hri.forget_after_s': 0.1}, log_dir=tmp_path)
    try:
        info = ros.node.create_publisher(CameraInfo, 'camera/color/camera_info',
                                         qos.OUTPUT_QOS)
        pub = ros.node.create_publisher(SkeletonArray, 'pose4d/parts/tracked/people',
                                        qos.OUTPUT_QOS)
        everyone = ros.collect(SkeletonArray, 'pose4d/skeletons', qos.OUTPUT_QOS)
        tracked = ros.collect(IdsList, 'humans/bodies/tracked', qos.OUTPUT_QOS)
        tf = ros.collect(TFMessage, '/tf', qos.TF_QOS)
        ros.wait_for_subscribers(pub)
        ros.wait_for_subscribers(info)
        ros.wait_for_publishers('humans/bodies/tracked')
        headers = [header_at(k) for k in range(12)]

        def send(k: int, people: bool = True) -> None:
            info.publish(intrinsics_to_msg(INTR, headers[k]))
            pub.publish(_two_people(k, headers[k]) if people
                        else SkeletonArray(header=headers[k]))

        # the first frame until the bodies' publishers are up, then subscribe to them
        ros.send_until_answered(lambda: send(0), lambda: any(m.ids for m in tracked),
                                'the first frame')
        per_body = {b: (ros.collect(Skeleton2D, f'humans/bodies/{b}/skeleton2d',
                                    qos.OUTPUT_QOS),
                        ros.collect(NormalizedRegionOfInterest2D, f'humans/bodies/{b}/roi',
                                    qos.OUTPUT_QOS)) for b in ('b1', 'b2')}
        for b in per_body:
            ros.wait_for_publishers(f'humans/bodies/{b}/skeleton2d')
            ros.wait_for_publishers(f'humans/bodies/{b}/roi')
        for k in range(1, 6):
            ros.send_until_answered(lambda k=k: send(k), lambda h=headers[k]: all(
                any(m.header == h for m in got) for got in (
                    *(s for pair in per_body.values() for s in pair), tracked)) and any(
                    t.header == h for m in tf for t in m.transforms), f'frame {k} on every topic')
        # nobody, for longer than hri.forget_after_s: the bodies' publishers go
        for k in range(6, 12):
            ros.send_until_answered(lambda k=k: send(k, people=False), lambda h=headers[k]: any(
                m.header == h for m in tracked), f'empty frame {k}')
        ros.spin_until(lambda: ros.node.count_publishers('/humans/bodies/b1/skeleton2d') == 0
                       and ros.node.count_publishers('/humans/bodies/b2/roi') == 0, 10,
                       'the bodies\' publishers destroyed')
    finally:
        assert node.stop() == 0, node.output()
    skeletons = {stamp_to_ns(m.header.stamp): skeletons_from_msg(m) for m in everyone}
    ids = {stamp_to_ns(m.header.stamp): sorted(m.ids) for m in tracked}
    assert all(ids[stamp_to_ns(h.stamp)] == ['b1', 'b2'] for h in headers[1:6])
    assert all(ids[stamp_to_ns(h.stamp)] == [] for h in headers[6:])
    frames = {}
    for m in tf:
        for t in m.transforms:
            frames.setdefault(stamp_to_ns(t.header.stamp), {})[t.child_frame_id] = t
    for h in headers[1:6]:
        stamp = stamp_to_ns(h.stamp)
        for person in skeletons[stamp]:
            b = f'b{person.track_id}'
            points = {stamp_to_ns(m.header.stamp): m for m in per_body[b][0]}[stamp]
            assert points.header.frame_id == h.frame_id and len(points.skeleton) == 18
            np.testing.assert_allclose(
                [(p.x, p.y, p.c) for p in points.skeleton],
                hri.skeleton2d(person, INTR.width, INTR.height), atol=1e-6)
            roi = {stamp_to_ns(m.header.stamp): m for m in per_body[b][1]}[stamp]
            assert roi.xmin < roi.xmax and roi.ymin < roi.ymax and 0 < roi.c <= 1
            # the body's frames: body_<id> in the camera frame, the links in it, each at its
            # joint's position once composed; the joints' own frames beside them
            got = frames[stamp]
            body = got[f'body_{b}']
            assert body.header.frame_id == h.frame_id
            r = _matrix([getattr(body.transform.rotation, c) for c in 'xyzw'])
            o = np.array([getattr(body.transform.translation, c) for c in 'xyz'])
            for name, link in hri.BODY_LINKS.items():
                t = got[f'{link}_{b}']
                assert t.header.frame_id == f'body_{b}'
                p = np.array([getattr(t.transform.translation, c) for c in 'xyz'])
                np.testing.assert_allclose(r @ p + o, person.xyz[person.index(name)],
                                           atol=1e-9)
            assert f'pose4d/{person.track_id}/head' in got


def test_ik_node_without_hri(ros, tmp_path):
    """hri.publish:=false: no /humans publisher at all."""
    node = start('ik', {'ik.use_depth': False, 'hri.publish': False}, log_dir=tmp_path)
    try:
        ros.spin_until(lambda: ros.node.count_publishers('/pose4d/skeletons') >= 1, 60,
                       'the ik node up')
        ros.spin_for(0.5)
        assert ros.node.count_publishers('/humans/bodies/tracked') == 0
    finally:
        assert node.stop() == 0, node.output()


def test_hri_msgs_is_an_interface_package():
    """The environment's hri_msgs, or the four body messages `make setup` built from
    ros_wheels/hri_msgs: the types HRI stacks subscribe with (a DDS reader matches a writer
    of the same type name only, so they cannot be a package of another name)."""
    from ament_index_python import get_resource
    from hri_msgs.msg import Skeleton2D

    content, _ = get_resource('rosidl_interfaces', 'hri_msgs')
    for name in ('IdsList', 'Skeleton2D', 'NormalizedPointOfInterest2D',
                 'NormalizedRegionOfInterest2D'):
        assert f'msg/{name}.msg' in content
    assert [getattr(Skeleton2D, k.upper()) for k in hri.SKELETON2D_KEYPOINTS] == list(range(18))
