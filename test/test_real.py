"""Real recordings: a folder of RGB-D frames with its camera_info.yaml (`datasets.frames_dir`),
and their scoring against a reference and hand labels (`evaluation.real`, `pose4d eval`)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from pose4d_ros.cli.main import main as pose4d_main
from pose4d_ros.core.joints import JointSet
from pose4d_ros.datasets import frames_dir
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.datasets.sources import load_frames, source_kind
from pose4d_ros.evaluation import real
from pose4d_ros.peer import NAMES as PEER_NAMES

REPO = Path(__file__).resolve().parents[1]
CAMERA_INFO = """image_width: 64
image_height: 48
camera_name: test
camera_matrix:
  rows: 3
  cols: 3
  data: [60.0, 0.0, 31.5, 0.0, 61.0, 23.5, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [{d}, 0.0, 0.0, 0.0, 0.0]
"""


def _write_sequence(root: Path, n: int = 3, *, distortion: float = 0.0) -> None:
    (root / 'color').mkdir(parents=True)
    (root / 'depth').mkdir()
    (root / 'camera_info.yaml').write_text(CAMERA_INFO.format(d=distortion))
    for k in range(n):
        bgr = np.zeros((48, 64, 3), np.uint8)
        bgr[:, :, 2] = 10 * k  # red in RGB
        cv2.imwrite(str(root / 'color' / f'{k + 1:04d}.png'), bgr)
        depth = np.full((48, 64), 2000 + k, np.uint16)
        depth[0, 0] = 0
        cv2.imwrite(str(root / 'depth' / f'{k + 1:04d}.png'), depth)


def test_a_folder_of_frames_reads_in_order_with_its_camera(tmp_path: Path) -> None:
    root = tmp_path / 'walk'
    _write_sequence(root)
    assert source_kind(root) == 'frames'
    frames = load_frames([str(root)], labelled=False, fps=10)
    assert [f.key for f in frames] == ['walk/0001', 'walk/0002', 'walk/0003']
    assert [f.stamp_ns - frames[0].stamp_ns for f in frames] == [0, 100_000_000, 200_000_000]
    assert {f.video for f in frames} == {'walk'}
    f = frames[2]
    assert f.color.shape == (48, 64, 3) and f.color[0, 0, 0] == 20  # RGB, not BGR
    assert np.isnan(f.depth_m[0, 0]) and f.depth_m[1, 1] == pytest.approx(2.002)
    k = f.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (60.0, 61.0, 31.5, 23.5, 64, 48)
    assert f.truth is None


def test_separate_frames_are_each_a_video_of_their_own(tmp_path: Path) -> None:
    root = tmp_path / 'masked'
    _write_sequence(root, 2)
    for k in (1, 2):  # color_NN.png / depth_NN.png beside camera_info.yaml
        (root / 'color' / f'{k:04d}.png').rename(root / f'color_{k:02d}.png')
        (root / 'depth' / f'{k:04d}.png').rename(root / f'depth_{k:02d}.png')
    (root / 'color').rmdir()
    frames = list(frames_dir.read_frames(root))
    assert [f.video for f in frames] == ['01', '02']
    assert frames[1].stamp_ns - frames[0].stamp_ns > 10**9  # a gap: the tracker starts anew
    held = list(frames_dir.read_frames(root, hold=3, fps=10))  # a still camera's stream
    assert [f.key for f in held] == ['masked/01'] * 3 + ['masked/02'] * 3
    assert np.diff([f.stamp_ns for f in held[:3]]).tolist() == [100_000_000] * 2
    assert held[3].stamp_ns - held[2].stamp_ns > 10**9


@pytest.mark.parametrize('damage, message', [
    (lambda root: (root / 'depth' / '0002.png').unlink(), '0002.png: no depth image'),
    (lambda root: (root / 'camera_info.yaml').write_text('image_width: [1\n'),
     'camera_info.yaml: not a readable camera calibration file'),
    (lambda root: (root / 'camera_info.yaml').write_text(CAMERA_INFO.format(d=0.1)),
     'must be rectified'),
    (lambda root: (root / 'camera_info.yaml').write_text(
        CAMERA_INFO.format(d=0).replace('image_width: 64', 'image_width: 80')),
     'camera_info is for 80x48 but the colour image'),
])
def test_a_damaged_folder_is_refused_naming_the_file(tmp_path: Path, damage, message) -> None:
    root = tmp_path / 'walk'
    _write_sequence(root)
    damage(root)
    with pytest.raises(ValueError, match=message):
        list(frames_dir.read_frames(root))


def _person(uv: np.ndarray, names=PEER_NAMES, track_id: int = 0) -> JointSet:
    return JointSet(tuple(names), uv, confidence=np.ones(len(names), np.float32),
                    track_id=track_id)


def _standing(x: float, height: float = 100.0) -> np.ndarray:
    """A standing person's joints (`PEER_NAMES`) at column x, head at row 10."""
    rows = {'head': 0.0, 'shoulder': 0.2, 'elbow': 0.35, 'wrist': 0.5, 'hip': 0.5,
            'knee': 0.75, 'ankle': 1.0}
    uv = []
    for n in PEER_NAMES:
        side = -1 if n.startswith('left') else (1 if n.startswith('right') else 0)
        uv.append((x + 10 * side, 10 + height * rows[n.split('_')[-1]]))
    return np.array(uv, np.float64)


def test_agreement_counts_joints_within_the_share_of_height(tmp_path: Path) -> None:
    frame = Frame(0, np.zeros((200, 200, 3), np.uint8), np.ones((200, 200), np.float32),
                  None, None, key='walk/0001')
    ref = _person(_standing(50))  # chain head-shoulders-hips-knees-ankles: 100 px
    ours = _standing(50)
    ours[:4] += (15, 0)  # 4 of 13 joints 15 px off: beyond 0.1 x 100 px, within 0.2
    ghost = _person(_standing(150), track_id=2)
    table = real.agreement([frame], [(ghost, _person(ours, track_id=1))], [ref])
    assert table['joints'] == 13 and table['scored_frames'] == 1
    assert table['agree@0.1'] == pytest.approx(100 * 9 / 13, abs=0.1)
    assert table['agree@0.2'] == 100.0
    # where ours lie, over the height, medians by group: the head 0.15 right, the left arm's
    # joints too (the right's in place), the legs in place
    assert table['offset_by_group'] == {
        'head': [0.15, 0.0], 'shoulder': [0.075, 0.0], 'elbow': [0.075, 0.0],
        'wrist': [0.075, 0.0], 'hip': [0.0, 0.0], 'knee': [0.0, 0.0], 'ankle': [0.0, 0.0]}
    assert 'labels' not in table
    labels = {'0001': [real.PersonLabel(box=(35, 5, 65, 115), head=(50, 10), feet=(50, 110))]}
    table = real.agreement([frame], [(ghost, _person(ours, track_id=1))], [ref], labels)
    lab = table['labels']
    assert (lab['labelled'], lab['ours'], lab['reference']) == (1, 1, 1)
    assert lab['ghosts'] == {'ours': 1, 'reference': 0} and lab['ghost_frames'] == ['walk/0001']
    # an unconfident reference joint is not scored; a reference with no person scores nothing
    arms = np.isin(np.arange(13), [2, 3, 5, 6])  # elbows and wrists
    weak = JointSet(ref.names, ref.uv, confidence=np.where(arms, 0.1, 0.9))
    assert real.agreement([frame], [(_person(ours),)], [weak])['joints'] == 9
    headless = JointSet(ref.names, ref.uv, confidence=np.where(np.arange(13) == 0, 0.1, 0.9))
    assert real.agreement([frame], [(_person(ours),)], [headless])['no_height'] == 1
    none = JointSet.missing(PEER_NAMES)
    assert real.agreement([frame], [(_person(ours),)], [none])['scored_frames'] == 0


def test_bone_steadiness_is_zero_for_rigid_bones_and_grows_with_jitter() -> None:
    from pose4d_ros.core.skeleton import SKELETON_14

    rng = np.random.default_rng(0)
    base = rng.normal(size=(14, 3)) * 0.3 + (0, 0, 2.5)
    frames = [Frame(k, np.zeros((4, 4, 3), np.uint8), None, None, None, video='v')
              for k in range(10)]

    def skeleton(xyz: np.ndarray) -> JointSet:
        return JointSet(SKELETON_14, np.zeros((14, 2)), xyz, track_id=1)

    rigid = real.bone_steadiness(frames, [(skeleton(base + 0.01 * k),) for k in range(10)])
    assert rigid == {'mad_rel': 0.0, 'within': 100.0, 'lengths': 80}  # 8 bones x 10 frames
    shaky = real.bone_steadiness(frames, [(skeleton(base + rng.normal(size=(14, 3)) * 0.1),)
                                          for _ in range(10)])
    assert shaky['mad_rel'] > 0.05 and shaky['within'] < 100.0
    assert real.bone_steadiness(frames[:2], [(), ()])['mad_rel'] is None  # too few to judge


def test_labels_are_read_and_checked(tmp_path: Path) -> None:
    good = {'source': 'x', 'frames': {'0001': [], '0002': [
        {'box': [1, 2, 30, 40], 'visible': 'partial', 'seated': True, 'head': [5, 6],
         'feet': None}]}}
    path = tmp_path / 'labels.json'
    path.write_text(json.dumps(good))
    labels = real.read_labels(path)
    assert labels['0001'] == [] and labels['0002'][0].seated
    assert labels['0002'][0].height_px is None
    good['frames']['0002'][0]['box'] = [30, 2, 1, 40]
    path.write_text(json.dumps(good))
    with pytest.raises(ValueError, match='frame 0002: box'):
        real.read_labels(path)


def test_eval_on_a_folder_without_labels_writes_people_and_drawings(tmp_path: Path) -> None:
    root = tmp_path / 'walk'
    _write_sequence(root)
    out = tmp_path / 'real.json'
    assert pose4d_main(['eval', str(root), '--json', str(out), '--fps', '10',
                        '--draw', str(tmp_path / 'draw')]) == 0
    result = json.loads(out.read_text())
    row = result['real']['rgbd_14+lspet_convnet']  # as the nodes run it: with the network
    assert result['frames'] == 3 and row['people_per_frame']['ours'] == 0.0  # a flat wall
    assert len(list((tmp_path / 'draw' / 'rgbd_14+lspet_convnet').glob('*.jpg'))) == 3


@pytest.mark.parametrize('folder', ['lab_walk', 'outdoor4', 'kinect2_masked'])
def test_hand_labels_cover_every_frame_of_the_real_folders(shared_data: Path, folder) -> None:
    path = REPO / 'labels' / 'real' / f'{folder}.json'
    labels = real.read_labels(path)
    frames = frames_dir._pairs(shared_data / 'real' / folder)[1]
    assert sorted(labels) == sorted(name for name, _, _ in frames)
    assert sum(map(len, labels.values())) > 0


def _write(path: Path, ros1: bool, store, msgs: list) -> None:
    """(topic, message, ns) in order into a ROS 1 bag or a rosbag2, as a recorder writes them."""
    if ros1:
        from rosbags.rosbag1 import Writer
        serialize = store.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer
        serialize = store.serialize_cdr
    with (Writer(path) if ros1 else Writer(path, version=8)) as writer:
        conns = {}
        for topic, msg, ns in msgs:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=store)
            writer.write(conns[topic], ns, serialize(msg, msg.__msgtype__))


def _camera_bag(path: Path, ros1: bool, n: int = 3) -> None:
    """A camera's recording as a driver writes it: its own topic names, bgr8 colour, 32FC1
    registered depth stamped 5 ms after the colour, camera_info, and a mono16 IR stream."""
    import numpy as np
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)
    t = store.types
    k = [60.0, 0.0, 31.5, 0.0, 61.0, 23.5, 0.0, 0.0, 1.0]

    def header(ns: int):
        stamp = t['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
        extra = {'seq': 0} if ros1 else {}
        return t['std_msgs/msg/Header'](stamp=stamp, frame_id='xtion_rgb_optical_frame',
                                         **extra)

    def image(ns: int, arr: np.ndarray, encoding: str):
        return t['sensor_msgs/msg/Image'](
            header=header(ns), height=arr.shape[0], width=arr.shape[1], encoding=encoding,
            is_bigendian=0, step=arr.strides[0], data=arr.reshape(-1).view(np.uint8))

    roi = t['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0,
                                                do_rectify=False)
    calib = ({'D': np.zeros(5), 'K': np.array(k), 'R': np.eye(3).ravel(),
              'P': np.zeros(12)} if ros1 else
             {'d': np.zeros(5), 'k': np.array(k), 'r': np.eye(3).ravel(), 'p': np.zeros(12)})
    msgs = []
    for i in range(n):
        ns = 1_700_000_000 * 10**9 + i * 33_333_333
        bgr = np.zeros((48, 64, 3), np.uint8)
        bgr[:, :, 0] = 50 + i  # blue
        depth = np.full((48, 64), 1.5 + i, np.float32)
        info = t['sensor_msgs/msg/CameraInfo'](
            header=header(ns), height=48, width=64, distortion_model='plumb_bob', binning_x=0,
            binning_y=0, roi=roi, **calib)
        msgs += [('/xtion/rgb/camera_info', info, ns), ('/xtion/rgb/image_raw',
                                                         image(ns, bgr, 'bgr8'), ns),
                 ('/xtion/depth_registered/image_raw',
                  image(ns + 5_000_000, depth, '32FC1'), ns + 5_000_000),
                 ('/xtion/ir/image', image(ns, np.zeros((48, 64), np.uint16), 'mono16'), ns)]
    _write(path, ros1, store, msgs)


@pytest.mark.parametrize('ros1', [True, False], ids=['ros1', 'rosbag2'])
def test_a_cameras_recording_is_read_with_its_topics_picked(tmp_path: Path, ros1) -> None:
    from pose4d_ros.datasets import camera_bag

    path = tmp_path / ('xtion.bag' if ros1 else 'xtion')
    _camera_bag(path, ros1)
    assert source_kind(path) == 'bag'
    # the depth is the registered one, not the IR stream (mono16 like a depth image)
    assert camera_bag.pick_topics(path) == ('/xtion/rgb/image_raw',
                                            '/xtion/depth_registered/image_raw',
                                            '/xtion/rgb/camera_info')
    frames = load_frames([str(path)], labelled=False)
    assert len(frames) == 3
    f = frames[1]
    assert f.color[0, 0, 2] == 51 and f.depth_m[0, 0] == pytest.approx(2.5)  # bgr8 -> RGB
    assert (f.intrinsics.fx, f.intrinsics.cy, f.intrinsics.width) == (60.0, 23.5, 64)
    assert f.stamp_ns == 1_700_000_000 * 10**9 + 33_333_333  # the colour image's stamp
    with pytest.raises(ValueError, match="no sensor_msgs/msg/Image or sensor_msgs/msg/"
                                         "CompressedImage topic '/nope'"):
        camera_bag.pick_topics(path, color_topic='/nope')
    out = tmp_path / 'real.json'
    assert pose4d_main(['eval', str(path), '--json', str(out),
                        '--depth-topic', '/xtion/depth_registered/image_raw']) == 0
    assert json.loads(out.read_text())['real']['rgbd_14+lspet_convnet']['frames'] == 3


def _compressed_bag(path: Path, ros1: bool, depth_format: str, n: int = 2) -> None:
    """A camera recorded through image_transport's codecs: JPEG colour on
    `.../image_raw/compressed`, `compressedDepth` PNG depth (16UC1 millimetres, or 32FC1 as
    quantised inverse depth) on `.../image_raw/compressedDepth`, and camera_info."""
    import struct

    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)
    t = store.types

    def header(ns: int):
        stamp = t['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
        return t['std_msgs/msg/Header'](stamp=stamp, frame_id='cam', **({'seq': 0} if ros1
                                                                         else {}))

    roi = t['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0,
                                                do_rectify=False)
    k = np.array([60.0, 0.0, 31.5, 0.0, 61.0, 23.5, 0.0, 0.0, 1.0])
    calib = ({'D': np.zeros(5), 'K': k, 'R': np.eye(3).ravel(), 'P': np.zeros(12)} if ros1
             else {'d': np.zeros(5), 'k': k, 'r': np.eye(3).ravel(), 'p': np.zeros(12)})
    a, b = 100.0 * 101.0, 1.0 - 100.0 * 101.0 / 10.0  # quantisation 100, 10 m far
    msgs = []
    for i in range(n):
        ns = 1_700_000_000 * 10**9 + i * 33_333_333
        bgr = np.zeros((48, 64, 3), np.uint8)
        bgr[:, :32] = (200, 40, 10)  # blue on the left
        ok, jpg = cv2.imencode('.jpg', bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
        metres = np.full((48, 64), 1.5 + i, np.float32)
        metres[0, 0] = np.nan
        if depth_format.startswith('16UC1'):
            png_of = np.nan_to_num(metres * 1000).astype(np.uint16)
            head = struct.pack('<iff', 1, 0.0, 0.0)
        else:
            png_of = np.where(np.isfinite(metres), a / metres + b, 0).astype(np.uint16)
            head = struct.pack('<iff', 0, a, b)
        ok2, png = cv2.imencode('.png', png_of)
        assert ok and ok2
        image = t['sensor_msgs/msg/CompressedImage']
        info = t['sensor_msgs/msg/CameraInfo'](
            header=header(ns), height=48, width=64, distortion_model='plumb_bob', binning_x=0,
            binning_y=0, roi=roi, **calib)
        msgs += [('/cam/color/camera_info', info, ns),
                 ('/cam/color/image_raw/compressed', image(
                     header=header(ns), format='bgr8; jpeg compressed bgr8',
                     data=np.frombuffer(jpg.tobytes(), np.uint8)), ns),
                 ('/cam/aligned_depth_to_color/image_raw/compressedDepth', image(
                     header=header(ns), format=depth_format,
                     data=np.frombuffer(head + png.tobytes(), np.uint8)), ns)]
    _write(path, ros1, store, msgs)


@pytest.mark.parametrize('ros1, depth_format', [
    (True, '16UC1; compressedDepth png'), (False, '32FC1; compressedDepth png')],
    ids=['ros1-16UC1', 'rosbag2-32FC1'])
def test_a_recording_through_image_transports_codecs_is_read(tmp_path: Path, ros1,
                                                             depth_format) -> None:
    from pose4d_ros.datasets import camera_bag

    path = tmp_path / ('cam.bag' if ros1 else 'cam')
    _compressed_bag(path, ros1, depth_format)
    assert camera_bag.pick_topics(path) == (
        '/cam/color/image_raw/compressed', '/cam/aligned_depth_to_color/image_raw/compressedDepth',
        '/cam/color/camera_info')
    frames = load_frames([str(path)], labelled=False)
    assert len(frames) == 2
    f = frames[1]
    assert np.abs(f.color[10, 5].astype(int) - (10, 40, 200)).max() <= 6  # JPEG, BGR -> RGB
    assert np.isnan(f.depth_m[0, 0])
    # 32FC1's inverse-depth quantisation: within a few millimetres at 2.5 m
    assert f.depth_m[20, 20] == pytest.approx(2.5, abs=0.005)
