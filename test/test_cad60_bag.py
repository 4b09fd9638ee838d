"""CAD-60 directory -> rosbag2 -> replay -> recorder -> rosbag2, and the converter's errors."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from conftest import REPO
from harness import executable, start
from numpy.testing import assert_allclose

from pose4d_ros.core.camera import cad60_intrinsics, depth_to_millimetres, project
from pose4d_ros.datasets import bag, cad60, cad60_bag

FIXTURE = REPO / 'test' / 'data' / 'cad60_fixture'


def _pose4d(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(executable('pose4d')), *map(str, args)], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_converter_writes_the_driver_topics_and_ground_truth(tmp_path, storage):
    out = tmp_path / 'bag'
    run = _pose4d('cad60-to-bag', FIXTURE, out, '--storage', storage)
    assert run.returncode == 0, run.stderr
    info = bag.topics(out)
    assert {t: i.count for t, i in info.items()} == {
        cad60_bag.COLOR_TOPIC: 2, cad60_bag.DEPTH_TOPIC: 2, cad60_bag.INFO_TOPIC: 2,
        cad60_bag.SKELETON_TOPIC: 2}
    video = cad60.list_videos(FIXTURE)[0]
    skeleton = cad60.read_skeleton(video.skeleton_path)
    frames = list(cad60.read_frames(FIXTURE))
    msgs = {}
    for m in bag.read_messages(out):
        msgs.setdefault(m.topic, []).append((m.timestamp_ns, bag.deserialize(m)))
    stamps = [t for t, _ in msgs[cad60_bag.COLOR_TOPIC]]
    for topic, items in msgs.items():
        assert [t for t, _ in items] == stamps, f'{topic} not stamped with the frame time'
        for t, msg in items:
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == t
            assert msg.header.frame_id == cad60_bag.FRAME_ID
    assert stamps == [f.stamp_ns for f in frames]
    assert stamps[1] - stamps[0] == cad60.FRAME_PERIOD_NS * int(np.diff(skeleton.frames)[0])
    for (_, color), (_, depth), frame in zip(msgs[cad60_bag.COLOR_TOPIC],
                                             msgs[cad60_bag.DEPTH_TOPIC], frames, strict=True):
        assert color.encoding == 'rgb8' and depth.encoding == '16UC1'
        assert np.array_equal(color.data.reshape(frame.color.shape), frame.color)
        assert np.array_equal(depth.data.view('<u2').reshape(frame.depth_m.shape),
                              depth_to_millimetres(frame.depth_m))
    info_msg = msgs[cad60_bag.INFO_TOPIC][0][1]
    intr = cad60_intrinsics()
    assert_allclose(info_msg.k, intr.k.ravel())
    gt = msgs[cad60_bag.SKELETON_TOPIC][0][1]
    assert [j.name for j in gt.joints][:4] == ['head', 'neck', 'torso', 'left_shoulder']
    xyz = np.array([[j.position.x, j.position.y, j.position.z] for j in gt.joints])
    uv = np.array([[j.u, j.v] for j in gt.joints])
    assert_allclose(xyz, skeleton.joints_optical()[0], atol=1e-9)
    assert_allclose(uv, project(xyz, intr), atol=1e-6)  # pixels agree with the 3-D joints


def test_a_vga_directory_carries_its_own_camera(tmp_path):
    """640x480 frames: camera_info, the frames' intrinsics and the ground-truth pixels are
    those of the true size, from the bag and from the directory alike."""
    import cv2

    vga = tmp_path / 'vga'
    shutil.copytree(FIXTURE, vga)
    for png in vga.rglob('*.png'):
        img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), cv2.resize(img, (640, 480), interpolation=cv2.INTER_NEAREST))
    intr = cad60_intrinsics(640, 480)
    out = tmp_path / 'bag'
    cad60_bag.convert(vga, out)
    info = bag.deserialize(next(iter(bag.read_messages(out, [cad60_bag.INFO_TOPIC]))))
    assert (info.width, info.height) == (640, 480)
    assert_allclose(info.k, intr.k.ravel())
    for frames in (list(cad60_bag.read_frames(out)), list(cad60.read_frames(vga))):
        assert len(frames) == 2
        for f in frames:
            assert f.intrinsics == intr and f.color.shape == (480, 640, 3), f.intrinsics
            assert_allclose(f.truth.uv, project(f.truth.xyz, intr), atol=1e-6)


def test_bag_is_self_describing_for_mcap(tmp_path):
    from mcap.reader import make_reader

    out = tmp_path / 'bag'
    assert _pose4d('cad60-to-bag', FIXTURE, out).returncode == 0
    with open(out / 'bag.mcap', 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert summary.statistics.message_count == 8
        assert {c.topic for c in summary.channels.values()} >= {cad60_bag.SKELETON_TOPIC}
        assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
    joint_array = schemas['pose4d_msgs/msg/JointArray']
    assert joint_array.encoding == 'ros2msg'
    text = joint_array.data.decode()
    assert 'MSG: pose4d_msgs/Joint' in text and 'float64[9] position_covariance' in text
    assert any(c.compression == 'zstd' for c in summary.chunk_indexes)


def test_cad60_round_trip_through_replay_and_recorder(tmp_path):
    source = tmp_path / 'source'
    assert _pose4d('cad60-to-bag', FIXTURE, source).returncode == 0
    out = tmp_path / 'recorded'
    topics = [t.lstrip('/') for t in bag.topics(source)]
    recorder = start('recorder', {'recorder.output': str(out), 'recorder.topics': topics},
                     log_dir=tmp_path)
    try:
        replay = start('replay', {'replay.bag': str(source),
                                  'replay.wait_for_subscribers': ['*=1']}, log_dir=tmp_path)
        assert replay.wait(30) == 0, replay.output()
    finally:
        assert recorder.stop() == 0, recorder.output()
    sent = [(m.topic, m.data) for m in bag.read_messages(source)]
    got = [(m.topic, m.data) for m in bag.read_messages(out)]
    assert len(got) == len(sent) == 8
    for topic in bag.topics(source):  # every message, identical bytes, in order per topic
        assert [d for t, d in got if t == topic] == [d for t, d in sent if t == topic]


def _break(tmp_path, how: str):
    root = tmp_path / 'cad'
    shutil.copytree(FIXTURE, root)
    video = cad60.list_videos(root)[0]
    if how == 'missing png':
        (video.frame_dir / 'Depth_2.png').unlink()
        return root, 'Depth_2.png'
    if how == 'field count':
        lines = video.skeleton_path.read_text().splitlines()
        lines[0] = lines[0].rstrip(',').rsplit(',', 1)[0] + ','
        video.skeleton_path.write_text('\n'.join(lines) + '\n')
        return root, '.txt:1: expected 171'
    if how == '8-bit depth':
        import cv2

        cv2.imwrite(str(video.frame_dir / 'Depth_1.png'), np.zeros((240, 320), np.uint8))
        return root, '16-bit'
    raise AssertionError(how)


@pytest.mark.parametrize('how', ['missing png', 'field count', '8-bit depth'])
def test_bad_input_fails_cleanly_without_partial_bag(tmp_path, how):
    root, words = _break(tmp_path, how)
    out = tmp_path / 'out'
    run = _pose4d('cad60-to-bag', root, out)
    assert run.returncode == 2
    assert words in run.stderr and 'error' in run.stderr
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith('.out')]


def test_existing_output_is_refused(tmp_path):
    (tmp_path / 'out').mkdir()
    run = _pose4d('cad60-to-bag', FIXTURE, tmp_path / 'out')
    assert run.returncode == 2 and 'exists already' in run.stderr


@pytest.mark.parametrize('people', [1, 3])
def test_every_persons_truth_goes_into_the_bag_and_back(tmp_path, people):
    """A several-person set adds /cad60/skeletons (SkeletonArray, track_id = person) and reads
    back into Frame.people; a one-person set's bag has no such topic and no people."""
    from helpers import write_utkinect

    from pose4d_ros.cli.main import main as pose4d_main
    from pose4d_ros.datasets import sources

    write_utkinect(tmp_path / 'ut', frames=40)
    root = tmp_path / 'set'
    assert pose4d_main(['synth', '--utkinect', str(tmp_path / 'ut'), '--out', str(root),
                        '--takes', 's01-s02', '--frames', '2', '--people', str(people),
                        '--quiet']) == 0
    out = tmp_path / 'bag'
    cad60_bag.convert(root, out)
    info = bag.topics(out)
    direct = list(cad60.read_frames(root))
    if people == 1:
        assert cad60_bag.SKELETONS_TOPIC not in info
    else:
        assert info[cad60_bag.SKELETONS_TOPIC].msgtype == 'pose4d_msgs/msg/SkeletonArray'
        assert info[cad60_bag.SKELETONS_TOPIC].count == len(direct) == 4
        msg = next(bag.deserialize(m) for m in bag.read_messages(out, [
            cad60_bag.SKELETONS_TOPIC]))
        assert [s.track_id for s in msg.skeletons] == [1, 2, 3]
        assert all(s.header.stamp == msg.header.stamp for s in msg.skeletons)
    for src in (cad60_bag.read_frames(out), sources.open_source(out)):
        back = list(src)
        assert len(back) == len(direct)
        for f, g in zip(back, direct, strict=True):
            assert f.stamp_ns == g.stamp_ns
            assert len(f.people) == len(g.people) == (0 if people == 1 else 3)
            assert f.truth.track_id == 1
            assert_allclose(f.truth.uv, g.truth.uv, atol=1e-9)
            for p, q in zip(f.people, g.people, strict=True):
                assert p.track_id == q.track_id and p.names == q.names
                assert_allclose(p.uv, q.uv, atol=1e-9)
                assert_allclose(p.xyz, q.xyz, atol=1e-12)
                assert np.array_equal(p.confidence, q.confidence)
                assert np.array_equal(p.source, q.source)
            assert np.array_equal(f.mask, g.mask)
