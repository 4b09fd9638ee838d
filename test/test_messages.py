"""pose4d_msgs over Fast DDS, and the one place where messages become arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest
from harness import RosPeer
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import cad60_intrinsics


def _joint_array():
    from geometry_msgs.msg import Point
    from pose4d_msgs.msg import Joint, JointArray
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import ns_to_stamp

    rng = np.random.default_rng(0)
    joints = []
    for i, (name, src) in enumerate([('head', Joint.DETECTED), ('neck', Joint.TRACKED),
                                     ('left_elbow', Joint.INFERRED),
                                     ('left_wrist', Joint.MISSING)]):
        cov = rng.normal(size=(3, 3))
        joints.append(Joint(
            name=name, u=float(10 * i + 0.25), v=float('nan') if src == Joint.MISSING else 7.5,
            position=Point(x=0.1 * i, y=-0.2, z=float('nan') if i == 3 else 2.5),
            confidence=0.25 * i, source=src, position_covariance=(cov @ cov.T).ravel().tolist()))
    return JointArray(header=Header(stamp=ns_to_stamp(1_234_567_890_123), frame_id='cam_optical'),
                      track_id=7, score=-0.5, joints=joints)


def test_joint_array_round_trip_over_dds():
    from pose4d_msgs.msg import JointArray

    sender, receiver = RosPeer('sender'), RosPeer('receiver')
    try:
        pub = sender.node.create_publisher(JointArray, 'pose4d/test_joints', 10)
        received = receiver.collect(JointArray, 'pose4d/test_joints')
        sender.wait_for_subscribers(pub)
        sent = _joint_array()
        pub.publish(sent)
        receiver.spin_until(lambda: received, 10, 'the JointArray')
    finally:
        sender.close()
        receiver.close()
    got = received[0]
    assert got.header == sent.header and got.track_id == 7 and got.score == -0.5
    assert [j.name for j in got.joints] == [j.name for j in sent.joints]
    for a, b in zip(got.joints, sent.joints, strict=True):
        assert a.source == b.source
        assert (a.u, a.confidence) == (b.u, pytest.approx(b.confidence))
        assert a.v == b.v or (math.isnan(a.v) and math.isnan(b.v))
        assert_array_equal([a.position.x, a.position.y, a.position.z],
                           [b.position.x, b.position.y, b.position.z])  # NaN == NaN here
        assert_array_equal(a.position_covariance, b.position_covariance)


def test_source_constants_match_core():
    from pose4d_msgs.msg import Joint

    assert (Joint.DETECTED, Joint.TRACKED, Joint.INFERRED, Joint.MISSING) == \
        (cj.DETECTED, cj.TRACKED, cj.INFERRED, cj.MISSING)


def test_joint_set_message_round_trip():
    from pose4d_ros.nodes.convert import joints_to_msg
    from pose4d_ros.wire import joints_from_msg

    msg = _joint_array()
    js = joints_from_msg(msg)
    assert js.names == ('head', 'neck', 'left_elbow', 'left_wrist')
    assert_array_equal(js.source, [cj.DETECTED, cj.TRACKED, cj.INFERRED, cj.MISSING])
    back = joints_to_msg(js, msg.header)
    again = joints_from_msg(back)
    assert_array_equal(again.uv, js.uv)
    assert_array_equal(again.xyz, js.xyz)
    assert_allclose(again.covariance, js.covariance)
    assert back.track_id == 7 and back.header == msg.header


@pytest.mark.parametrize('encoding', ['16UC1', '32FC1'])
@pytest.mark.parametrize('padding', [0, 6])
@pytest.mark.parametrize('bigendian', [False, True])
def test_depth_image_both_encodings(encoding, padding, bigendian):
    import array

    from sensor_msgs.msg import Image

    from pose4d_ros.wire import depth_from_msg

    rng = np.random.default_rng(0)
    metres = rng.uniform(0.5, 4.0, size=(4, 5)).astype(np.float32)
    metres[0, 0] = np.nan
    if encoding == '16UC1':
        raw = np.where(np.isnan(metres), 0, np.rint(metres * 1000)).astype(np.uint16)
        expected = np.where(raw == 0, np.nan, raw * 0.001).astype(np.float32)
    else:
        raw = np.where(np.isnan(metres), 0.0, metres).astype(np.float32)  # 0 = no reading too
        expected = np.where(raw == 0, np.nan, raw)
    raw = raw.astype(raw.dtype.newbyteorder('>' if bigendian else '<'))
    rows = raw.view(np.uint8).reshape(4, -1)
    rows = np.hstack([rows, np.full((4, padding), 0xAB, np.uint8)])  # stride > row
    msg = Image(height=4, width=5, encoding=encoding, is_bigendian=int(bigendian),
                step=rows.shape[1])
    msg.data = array.array('B', rows.tobytes())
    got = depth_from_msg(msg)
    assert got.dtype == np.float32
    assert_allclose(got, expected, rtol=0, atol=1e-6, equal_nan=True)


def test_bad_images_are_refused_with_the_reason():
    import array

    from sensor_msgs.msg import Image

    from pose4d_ros.wire import color_from_msg, depth_from_msg

    msg = Image(height=2, width=2, encoding='rgb8', step=6)
    msg.data = array.array('B', bytes(12))
    assert color_from_msg(msg).shape == (2, 2, 3)
    with pytest.raises(ValueError, match='depth image encoding'):
        depth_from_msg(msg)
    msg.step = 4
    with pytest.raises(ValueError, match='step 4 is smaller'):
        color_from_msg(msg)
    msg.step, msg.data = 6, array.array('B', bytes(5))
    with pytest.raises(ValueError, match='expected 12'):
        color_from_msg(msg)
    msg.encoding = 'yuv422'
    with pytest.raises(ValueError, match='unsupported image encoding'):
        color_from_msg(msg)


def test_color_and_camera_info_round_trip():
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg
    from pose4d_ros.wire import color_from_msg, intrinsics_from_msg

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, size=(3, 4, 3), dtype=np.uint8)
    assert_array_equal(color_from_msg(array_to_image(rgb, 'rgb8', Header())), rgb)
    assert_array_equal(color_from_msg(array_to_image(rgb[..., ::-1], 'bgr8', Header())), rgb)
    intr = cad60_intrinsics()
    assert intrinsics_from_msg(intrinsics_to_msg(intr, Header())) == intr


@pytest.mark.parametrize('encoding,shape,dtype', [
    ('rgb8', (5, 7, 3), np.uint8), ('mono8', (4, 3), np.uint8), ('16UC1', (3, 5), np.uint16),
    ('32FC1', (2, 3), np.float32)])
@pytest.mark.parametrize('frame_id', ['', 'cam', 'camera_depth_optical_frame'])
def test_image_to_cdr_is_the_serialised_message(encoding, shape, dtype, frame_id):
    """The foreground's image bytes decode to the message array_to_image builds, and have its
    length (a non-contiguous array included)."""
    from builtin_interfaces.msg import Time
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import array_to_image
    from pose4d_ros.wire import image_to_cdr

    rng = np.random.default_rng(len(frame_id))
    img = (rng.random((shape[0], 2 * shape[1], *shape[2:])) * 200).astype(dtype)[:, ::2]
    header = Header(frame_id=frame_id, stamp=Time(sec=7, nanosec=8))
    msg = array_to_image(img, encoding, header)
    data = image_to_cdr(img, encoding, header)
    assert len(data) == len(serialize_message(msg))
    back = deserialize_message(data, Image)
    assert back == msg
    with pytest.raises(ValueError, match='does not fit'):
        image_to_cdr(img[..., None], encoding, header)


@pytest.mark.parametrize('encoding,shape,dtype', [
    ('rgb8', (5, 7, 3), np.uint8), ('bgr8', (3, 2, 3), np.uint8), ('mono8', (4, 3), np.uint8),
    ('16UC1', (3, 5), np.uint16), ('32FC1', (2, 3), np.float32)])
@pytest.mark.parametrize('frame_id', ['', 'cam', 'camera_depth_optical_frame'])
def test_image_from_cdr_reads_what_the_message_holds(encoding, shape, dtype, frame_id):
    """An Image read in place from its bytes gives the arrays and header the deserialised
    message gives (a padded row stride included), and damaged bytes are refused."""
    from builtin_interfaces.msg import Time
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import array_to_image
    from pose4d_ros.wire import image_from_cdr, image_to_array

    rng = np.random.default_rng(len(frame_id))
    msg = array_to_image((rng.random(shape) * 200).astype(dtype), encoding,
                         Header(frame_id=frame_id, stamp=Time(sec=7, nanosec=8)))
    msg.step += 4  # rows padded, as some drivers send them
    msg.data = bytes(msg.step * msg.height)
    data = serialize_message(msg)
    view, full = image_from_cdr(data), deserialize_message(data, Image)
    assert_array_equal(image_to_array(view), image_to_array(full))
    assert (view.header.stamp.sec, view.header.stamp.nanosec, view.header.frame_id) == (
        7, 8, frame_id)
    assert (view.height, view.width, view.encoding, view.step) == (
        full.height, full.width, full.encoding, full.step)
    for bad, reason in ((data[:-1], 'announced'), (data[:30], 'too short|bad string'),
                        (b'\x00\x00\x00\x00' + data[4:], 'not little-endian')):
        with pytest.raises(ValueError, match=reason):
            image_from_cdr(bad)


@pytest.mark.parametrize('frame_id', ['', 'c', 'camera_color_optical_frame'])
@pytest.mark.parametrize('n', [0, 1, 10, 14])
def test_joints_to_cdr_is_the_serialised_message(frame_id, n):
    """The bytes the nodes publish decode to exactly the message joints_to_msg builds (and have
    its length: the same layout, alignment included)."""
    from builtin_interfaces.msg import Time
    from pose4d_msgs.msg import JointArray
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Header

    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.core.skeleton import SKELETON_14
    from pose4d_ros.nodes.convert import joints_to_msg
    from pose4d_ros.wire import joints_to_cdr

    rng = np.random.default_rng(n)
    uv = rng.normal(size=(n, 2)) * 100
    uv[:1] = np.nan
    js = JointSet(SKELETON_14[:n], uv, rng.normal(size=(n, 3)),
                  confidence=rng.random(n).astype(np.float32),
                  source=rng.integers(0, 4, n).astype(np.uint8),
                  covariance=rng.normal(size=(n, 3, 3)), score=0.25, track_id=n + 3)
    header = Header(frame_id=frame_id, stamp=Time(sec=1234567, nanosec=890))
    msg = joints_to_msg(js, header)
    data = joints_to_cdr(js, header)
    assert len(data) == len(serialize_message(msg))
    back = deserialize_message(data, JointArray)
    assert back.header == header and back.track_id == msg.track_id and back.score == msg.score
    for a, b in zip(back.joints, msg.joints, strict=True):
        assert (a.name, a.source) == (b.name, b.source)
        assert np.float32(a.confidence) == np.float32(b.confidence)
        assert_array_equal([a.u, a.v, a.position.x, a.position.y, a.position.z],
                           [b.u, b.v, b.position.x, b.position.y, b.position.z])
        assert_array_equal(a.position_covariance, b.position_covariance)


@pytest.mark.parametrize('frame_id', ['', 'c', 'camera_color_optical_frame'])
def test_tf_to_cdr_is_the_serialised_message(frame_id):
    """Every person's located joints on /tf: the bytes decode to one identity transform per
    joint that is neither MISSING nor non-finite, named `<prefix>/<track>/<joint>`, and have
    the serialised message's length (names of several lengths: every alignment)."""
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Header
    from tf2_msgs.msg import TFMessage

    from pose4d_ros.core.joints import DETECTED, INFERRED, MISSING, TRACKED, JointSet
    from pose4d_ros.core.skeleton import SKELETON_14
    from pose4d_ros.wire import tf_to_cdr

    rng = np.random.default_rng(7)
    people = []
    for track in (3, 12):
        xyz = rng.normal(size=(14, 3))
        xyz[2] = np.nan
        source = np.full(14, (DETECTED, TRACKED, INFERRED)[track % 3], np.uint8)
        source[5] = MISSING
        people.append(JointSet(SKELETON_14, rng.normal(size=(14, 2)), xyz, source=source,
                               track_id=track))
    header = Header(frame_id=frame_id, stamp=Time(sec=1234567, nanosec=890))
    want = TFMessage(transforms=[
        TransformStamped(header=header, child_frame_id=f'pose4d/{p.track_id}/{name}',
                         transform=Transform(translation=Vector3(x=x, y=y, z=z),
                                             rotation=Quaternion(w=1.0)))
        for p in people
        for name, (x, y, z), s in zip(p.names, p.xyz.tolist(), p.source, strict=True)
        if s != MISSING and np.isfinite([x, y, z]).all()])
    assert len(want.transforms) == 2 * (14 - 2)
    data = tf_to_cdr(people, header, 'pose4d')
    assert len(data) == len(serialize_message(want))
    assert deserialize_message(data, TFMessage) == want
    # nobody located: nothing to send
    assert tf_to_cdr([JointSet.missing(SKELETON_14)], header, 'pose4d') is None
    assert tf_to_cdr([], header, 'pose4d') is None


@pytest.mark.parametrize('people', [0, 1, 3])
def test_skeletons_to_cdr_is_the_serialised_message(people):
    """Several people's bytes (names of several lengths, so every alignment is exercised)
    decode to the SkeletonArray skeletons_to_msg builds, and have its length."""
    from builtin_interfaces.msg import Time
    from pose4d_msgs.msg import SkeletonArray
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Header

    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.core.skeleton import SKELETON_14
    from pose4d_ros.nodes.convert import skeletons_to_msg
    from pose4d_ros.wire import skeletons_to_cdr

    rng = np.random.default_rng(people)
    sets = []
    for k in range(people):
        n = (14, 3, 1)[k]
        sets.append(JointSet(SKELETON_14[k:k + n], rng.normal(size=(n, 2)) * 100,
                             rng.normal(size=(n, 3)), confidence=rng.random(n).astype(np.float32),
                             source=rng.integers(0, 4, n).astype(np.uint8),
                             covariance=rng.normal(size=(n, 3, 3)), score=0.5, track_id=k + 1))
    header = Header(frame_id='cam', stamp=Time(sec=12, nanosec=34))
    data = skeletons_to_cdr(sets, header)
    msg = skeletons_to_msg(sets, header)
    # the same length (layout and alignment); the padding rclpy writes is not zeroed, so the
    # bytes are compared by what they decode to
    assert len(data) == len(serialize_message(msg))
    back = deserialize_message(data, SkeletonArray)
    assert back.header == header and len(back.skeletons) == people
    for got, want in zip(back.skeletons, msg.skeletons, strict=True):
        assert (got.header, got.track_id, got.score) == (want.header, want.track_id, want.score)
        assert [(j.name, j.source, j.u, j.v, j.position, j.confidence,
                 list(j.position_covariance)) for j in got.joints] == \
            [(j.name, j.source, j.u, j.v, j.position, np.float32(j.confidence),
              list(j.position_covariance)) for j in want.joints]


def _people(count: int, seed: int = 0) -> list:
    """`count` people of 14, 3, 1, 14 ... joints (names of several lengths: every alignment)."""
    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.core.skeleton import SKELETON_14

    rng = np.random.default_rng(seed)
    sets = []
    for k in range(count):
        n = (14, 3, 1)[k % 3]
        uv = rng.normal(size=(n, 2)) * 100
        uv[:1] = np.nan
        sets.append(JointSet(SKELETON_14[k % 3:k % 3 + n], uv, rng.normal(size=(n, 3)),
                             confidence=rng.random(n).astype(np.float32),
                             source=rng.integers(0, 4, n).astype(np.uint8),
                             covariance=rng.normal(size=(n, 3, 3)), score=0.5, track_id=k + 1))
    return sets


def _same_joints(got, want) -> None:
    assert (got.names, got.track_id, got.score) == (want.names, want.track_id, want.score)
    for name in ('uv', 'xyz', 'confidence', 'source', 'covariance'):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.flags.c_contiguous and not a.flags.writeable, name
        assert_array_equal(a, b, err_msg=name)


@pytest.mark.parametrize('people', [0, 1, 3])
@pytest.mark.parametrize('frame_id', ['', 'cam', 'camera_color_optical_frame'])
def test_skeletons_from_cdr_reads_what_the_message_holds(people, frame_id):
    """The nodes' reader of SkeletonArray bytes gives what deserialising the message and
    reading its fields gives, from rclpy's serialisation and from ours alike."""
    from builtin_interfaces.msg import Time
    from pose4d_msgs.msg import JointArray, SkeletonArray
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Header

    from pose4d_ros.nodes.convert import joints_to_msg, skeletons_to_msg
    from pose4d_ros.wire import (
        cdr_header,
        joints_from_cdr,
        joints_from_msg,
        skeletons_from_cdr,
        skeletons_from_msg,
        skeletons_to_cdr,
    )

    sets = _people(people, seed=people)
    header = Header(frame_id=frame_id, stamp=Time(sec=-3, nanosec=999_999_999))
    for data in (serialize_message(skeletons_to_msg(sets, header)),
                 skeletons_to_cdr(sets, header)):
        sec, nanosec, frame, at = cdr_header(data)
        assert (sec, nanosec, frame) == (-3, 999_999_999, frame_id)
        want = skeletons_from_msg(deserialize_message(data, SkeletonArray))
        got = skeletons_from_cdr(data, at)
        assert len(got) == len(want) == people
        for a, b in zip(got, want, strict=True):
            _same_joints(a, b)
    for joints in sets:
        data = serialize_message(joints_to_msg(joints, header))
        _same_joints(joints_from_cdr(data), joints_from_msg(deserialize_message(data, JointArray)))


def test_skeletons_from_cdr_refuses_damaged_bytes():
    """Cut short, a byte changed anywhere, or another encapsulation: a ValueError or people
    that decode (values are checked by the stages), never another exception."""
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

    from pose4d_ros.wire import cdr_header, skeletons_from_cdr, skeletons_to_cdr

    data = skeletons_to_cdr(_people(2), Header(frame_id='cam', stamp=Time(sec=1, nanosec=2)))
    refused = 0
    for k in range(len(data)):
        for damaged in (data[:k], data[:k] + bytes([data[k] ^ 0xff]) + data[k + 1:]):
            try:
                skeletons_from_cdr(damaged, cdr_header(damaged)[3])
            except ValueError:
                refused += 1
    # every cut is refused, and so is any change to the encapsulation, a length or a name
    assert refused >= len(data) + 4
    with pytest.raises(ValueError, match='little-endian'):
        cdr_header(b'\x00\x00' + data[2:])


def test_warm_up_compiles_what_a_camera_frame_needs():
    """After `wire.warm_up`, a depth image read from a message's bytes (a read-only view, in
    either encoding, at any size) and written back in millimetres meets no kernel signature
    that is not compiled yet: the first camera frame compiles nothing (on a fresh install it
    did, for 140-220 ms)."""
    from pose4d_ros import wire
    from pose4d_ros.core import camera
    from pose4d_ros.core.camera import depth_to_millimetres

    wire.warm_up()
    kernels = (camera._metres, camera._millimetres)
    before = [len(k.signatures) for k in kernels]
    header = wire.cdr.CdrHeader(wire.cdr.CdrStamp(1, 2), 'camera')
    metres = np.random.default_rng(0).uniform(0.5, 6.0, (240, 320)).astype(np.float32)
    for img, encoding in ((depth_to_millimetres(metres), '16UC1'), (metres, '32FC1')):
        depth = wire.depth_from_msg(wire.image_from_cdr(wire.image_to_cdr(img, encoding, header)))
        assert_allclose(depth, metres, atol=5e-4)
        depth_to_millimetres(depth)
    assert [len(k.signatures) for k in kernels] == before
