"""CAD-60 reader and writer: the hand-written fixture, left/right, projections, bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.core.camera import cad60_intrinsics, depth_to_millimetres, project
from pose4d_ros.core.joints import DETECTED, MISSING
from pose4d_ros.core.skeleton import CAD60_JOINTS
from pose4d_ros.datasets import cad60

FIXTURE = Path(__file__).resolve().parent / 'data' / 'cad60_fixture'
VIDEO_ID = '0512164529'
J = CAD60_JOINTS.index


@pytest.fixture()
def person_dir(tmp_path: Path) -> Path:
    """A writable copy of the fixture's data1/."""
    dst = tmp_path / 'data1'
    shutil.copytree(FIXTURE / 'data1', dst)
    return dst


def test_read_fixture_skeleton_values() -> None:
    skel = cad60.read_skeleton(FIXTURE / 'data1' / f'{VIDEO_ID}.txt')
    assert_array_equal(skel.frames, [1, 2])
    assert skel.joints_mm.shape == (2, 15, 3)
    assert skel.orientations.shape == (2, 11, 3, 3)
    # Head (slot 1, unaffected by mirroring), frame 2 is shifted by 5.5 mm in x.
    assert_allclose(skel.joints_mm[:, J('head')], [[10, 650, 2500], [15.5, 650, 2500]])
    # The file's slot 6 ("right shoulder") is the person's anatomical left shoulder.
    assert_allclose(skel.joints_mm[0, J('left_shoulder')], [190, 430, 2505])
    assert_allclose(skel.joints_mm[0, J('right_shoulder')], [-180, 430, 2510])
    # Slot 13 ("right hand") has confidence 0 in frame 2 -> anatomical left hand.
    assert_array_equal(skel.joint_conf[:, J('left_hand')], [1, 0])
    assert_array_equal(skel.joint_conf[:, J('right_hand')], [1, 1])
    assert_allclose(skel.orientations[1, 4], np.eye(3))
    assert_array_equal(skel.orientation_conf, np.ones((2, 11)))


def test_facing_person_anatomical_left_is_image_right() -> None:
    """A person facing the camera has their left shoulder at larger u than their right."""
    skel = cad60.read_skeleton(FIXTURE / 'data1' / f'{VIDEO_ID}.txt')
    uv = skel.pixels()
    for side in ('shoulder', 'elbow', 'hip', 'knee', 'hand', 'foot'):
        assert np.all(uv[:, J(f'left_{side}'), 0] > uv[:, J(f'right_{side}'), 0]), side
    # ... and the head above the feet (v grows downwards).
    assert np.all(uv[:, J('head'), 1] < uv[:, J('left_foot'), 1])


def test_perspective_formula_and_optical_frame_agree() -> None:
    rng = np.random.default_rng(0)
    world = np.column_stack([rng.uniform(-800, 800, 50), rng.uniform(-900, 900, 50),
                             rng.uniform(1500, 4000, 50)])
    uv = cad60.project_perspective(world)
    assert_allclose(uv[:, 0], 160 + 285.171 * world[:, 0] / world[:, 2], atol=1e-9)
    assert_allclose(uv[:, 1], 120 - 285.117 * world[:, 1] / world[:, 2], atol=1e-9)
    optical = cad60.world_to_optical(world)
    assert_allclose(project(optical, cad60_intrinsics()), uv, atol=1e-9)
    # 640x480: focal lengths double.
    uv2 = cad60.project_perspective(world, cad60_intrinsics(640, 480))
    assert_allclose(uv2, 2 * uv, atol=1e-9)


def test_affine_fit_is_close_to_perspective_near_2_6_m() -> None:
    skel = cad60.read_skeleton(FIXTURE / 'data1' / f'{VIDEO_ID}.txt')
    persp = skel.pixels(model='perspective')
    affine = skel.pixels(model='affine')
    err = np.linalg.norm(persp - affine, axis=-1)
    # The README's fit is a few pixels off the OpenNI model at 2.5 m (1-6 px on this person):
    # close, but a different model.
    assert 1.0 < err.mean() < 6.0 and err.max() < 8.0
    with pytest.raises(ValueError, match='projection model'):
        skel.pixels(model='orthographic')


def test_lost_joint_projects_to_nan() -> None:
    uv = cad60.project_perspective(np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 2000.0]]))
    assert np.all(np.isnan(uv[0])) and np.all(np.isfinite(uv[1]))
    assert np.all(np.isnan(cad60.project_affine(np.zeros((1, 3)))))


def test_list_videos_and_read_frames() -> None:
    for root in (FIXTURE, FIXTURE / 'data1'):
        videos = cad60.list_videos(root)
        assert [(v.person, v.video_id, v.activity) for v in videos] == \
            [('data1', VIDEO_ID, 'drinking water')]
    frames = list(cad60.read_frames(FIXTURE))
    assert [Path(f.key).name for f in frames] == ['RGB_1.png', 'RGB_2.png']
    assert frames[1].stamp_ns - frames[0].stamp_ns == cad60.FRAME_PERIOD_NS
    f = frames[0]
    assert f.video == f'data1/{VIDEO_ID}' and f.intrinsics == cad60_intrinsics()
    assert f.color.dtype == np.uint8 and f.color.shape == (240, 320, 3)
    assert f.depth_m.dtype == np.float32 and f.depth_m.shape == (240, 320)
    assert tuple(f.color[0, 0]) == (200, 190, 170)  # RGB order, not OpenCV's BGR
    assert depth_to_millimetres(f.depth_m)[100, 150] == 2501 and np.isnan(f.depth_m[100, 5])
    assert f.mask is None
    skeleton = cad60.read_skeleton(videos[0].skeleton_path)
    assert f.truth.names == CAD60_JOINTS
    assert_allclose(f.truth.uv, skeleton.pixels()[0])
    assert_allclose(f.truth.xyz, skeleton.joints_optical()[0])


def test_skeleton_write_read_roundtrip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n = 4
    rot = np.linalg.qr(rng.normal(size=(n * 11, 3, 3)))[0].reshape(n, 11, 3, 3)
    skel = cad60.Skeleton(
        frames=np.array([1, 2, 5, 9]),
        joints_mm=rng.uniform(-1000, 3000, (n, 15, 3)),
        joint_conf=rng.choice([0.0, 0.5, 1.0], (n, 15)),
        orientations=rot,
        orientation_conf=rng.choice([0.0, 1.0], (n, 11)),
    )
    path = tmp_path / '0000000001.txt'
    cad60.write_skeleton(path, skel)
    lines = path.read_text().splitlines()
    assert lines[-1] == 'END' and len(lines) == n + 1
    assert all(line.endswith(',') and len(line.split(',')) == 172 for line in lines[:-1])
    # The file's slot 4 ("left shoulder", X at field 11 + 14 * 3) holds the anatomical right.
    assert_allclose(float(lines[0].split(',')[11 + 14 * 3]),
                    skel.joints_mm[0, J('right_shoulder'), 0], rtol=1e-5)
    back = cad60.read_skeleton(path)
    assert_array_equal(back.frames, skel.frames)
    assert_allclose(back.joints_mm, skel.joints_mm, rtol=1e-5, atol=1e-3)  # 6 digits
    assert_allclose(back.orientations, skel.orientations, atol=1e-5)
    assert_array_equal(back.joint_conf, skel.joint_conf)
    assert_array_equal(back.orientation_conf, skel.orientation_conf)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['0000000001.txt']  # no temp files


def test_frame_writers_roundtrip_and_mask_is_ignored(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    person = tmp_path / 'data3'
    (person / '0000000007').mkdir(parents=True)
    cad60.write_activity_labels(person / 'activityLabel.txt', {'0000000007': 'walk'})
    skel = cad60.read_skeleton(FIXTURE / 'data1' / f'{VIDEO_ID}.txt')
    cad60.write_skeleton(person / '0000000007.txt', skel)
    rgb = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    depth = rng.integers(0, 5000, (24, 32), dtype=np.uint16)
    mask = rng.random((24, 32)) > 0.5
    for k in (1, 2):
        cad60.write_frame(person / '0000000007', k, rgb, depth, mask)
    video = cad60.list_videos(tmp_path)[0]
    assert (video.person, video.video_id, video.activity) == ('data3', '0000000007', 'walk')
    frames = list(cad60.read_frames(tmp_path))
    assert_array_equal(frames[1].color, rgb)
    assert_array_equal(depth_to_millimetres(frames[1].depth_m), depth)
    assert_array_equal(frames[0].mask, mask)
    assert not any(p.name.endswith('.tmp') for p in (person / '0000000007').iterdir())


def _replace_line(path: Path, lineno: int, new: str) -> None:
    lines = path.read_text().splitlines()
    lines[lineno - 1] = new
    path.write_text('\n'.join(lines) + '\n')


@pytest.mark.parametrize(('edit', 'match'), [
    (lambda line: line.rsplit(',', 2)[0] + ',', r':2: expected 171 .* numbers, got 170'),
    (lambda line: line + '7,', r':2: expected 171 .* numbers, got 172'),
    (lambda line: line.replace(',650,', ',6S0,', 1), r":2: non-numeric field '6S0'"),
    (lambda line: '1' + line[1:], r':2: frame number 1 does not increase'),
    (lambda line: '2.5' + line[1:], r':2: frame number .* not a positive integer'),
])
def test_bad_skeleton_lines(person_dir: Path, edit, match: str) -> None:
    path = person_dir / f'{VIDEO_ID}.txt'
    line2 = path.read_text().splitlines()[1]
    _replace_line(path, 2, edit(line2))
    with pytest.raises(ValueError, match=f'{VIDEO_ID}.txt{match}'):
        cad60.read_skeleton(path)


def test_missing_end_and_data_after_end(person_dir: Path) -> None:
    path = person_dir / f'{VIDEO_ID}.txt'
    lines = path.read_text().splitlines()
    path.write_text('\n'.join(lines[:-1]) + '\n')
    with pytest.raises(ValueError, match=f'{VIDEO_ID}.txt: missing the END line'):
        cad60.read_skeleton(path)
    path.write_text('\n'.join(lines + [lines[0]]) + '\n')
    with pytest.raises(ValueError, match=f'{VIDEO_ID}.txt:4: data after the END line'):
        cad60.read_skeleton(path)


def test_missing_png(person_dir: Path) -> None:
    (person_dir / VIDEO_ID / 'Depth_2.png').unlink()
    video = cad60.list_videos(person_dir)[0]
    frames = cad60.read_frames(person_dir)
    next(frames)
    with pytest.raises(ValueError, match='Depth_2.png: image file not found'):
        next(frames)
    with pytest.raises(ValueError, match='RGB_9.png: image file not found'):
        cad60.load_frame(video.frame_dir, 9)
    shutil.copy(video.frame_dir / 'Depth_1.png', video.frame_dir / 'Depth_2.png')
    cad60.write_mask(video.frame_dir / 'Mask_1.png', np.ones((240, 320), bool))
    with pytest.raises(ValueError, match='Mask_2.png: image file not found'):
        list(cad60.read_frames(person_dir))


def test_8bit_depth_is_refused(person_dir: Path) -> None:
    path = person_dir / VIDEO_ID / 'Depth_1.png'
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), (depth // 16).astype(np.uint8))
    with pytest.raises(ValueError, match='Depth_1.png: depth image must be 16-bit.*uint8'):
        cad60.load_frame(person_dir / VIDEO_ID, 1)


def test_3channel_16bit_depth_is_refused(person_dir: Path) -> None:
    path = person_dir / VIDEO_ID / 'Depth_1.png'
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), np.dstack([depth] * 3))
    with pytest.raises(ValueError, match='Depth_1.png: depth image must be single-channel'):
        cad60.load_depth(path)


def test_rgb_depth_size_mismatch(person_dir: Path) -> None:
    path = person_dir / VIDEO_ID / 'RGB_2.png'
    rgb = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), cv2.resize(rgb, (640, 480)))
    with pytest.raises(ValueError, match='Depth_2.png: depth is 320x240 but RGB_2.png is 640x480'):
        cad60.load_frame(person_dir / VIDEO_ID, 2)


def test_grey_rgb_and_garbage_png_are_refused(person_dir: Path) -> None:
    path = person_dir / VIDEO_ID / 'RGB_1.png'
    cv2.imwrite(str(path), np.zeros((240, 320), np.uint8))
    with pytest.raises(ValueError, match='RGB_1.png: RGB image must have 3 channels'):
        cad60.load_rgb(path)
    path.write_bytes(b'not a png')
    with pytest.raises(ValueError, match='RGB_1.png: not a readable image'):
        cad60.load_rgb(path)


def test_bad_activity_labels_and_missing_skeleton(person_dir: Path) -> None:
    labels = person_dir / 'activityLabel.txt'
    labels.write_text(f'{VIDEO_ID},drinking water,\n0512170000,cooking,\n')
    with pytest.raises(ValueError, match='0512170000 listed but .*0512170000.txt is missing'):
        cad60.list_videos(person_dir)
    labels.write_text(f'{VIDEO_ID},drinking water,\njust-an-id\n')
    with pytest.raises(ValueError, match='activityLabel.txt:2: expected "id,activity name,"'):
        cad60.read_activity_labels(labels)
    with pytest.raises(ValueError, match='no activityLabel.txt'):
        cad60.list_videos(person_dir / VIDEO_ID)


@pytest.mark.parametrize(('labels', 'match'), [
    ({'123': 'walk'}, 'video id must be 10 digits'),
    ({'0000000001': 'walk, fast'}, 'without commas'),
])
def test_write_activity_labels_refuses_bad_values(tmp_path: Path, labels, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        cad60.write_activity_labels(tmp_path / 'activityLabel.txt', labels)
    assert list(tmp_path.iterdir()) == []


def test_writers_refuse_wrong_dtypes(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match='depth must be .* uint16'):
        cad60.write_depth(tmp_path / 'Depth_1.png', np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match=r'RGB image must be \(H, W, 3\) uint8'):
        cad60.write_rgb(tmp_path / 'RGB_1.png', np.zeros((4, 4, 3), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_skeleton_shape_validation() -> None:
    with pytest.raises(ValueError, match='joints_mm has shape'):
        cad60.Skeleton(np.array([1]), np.zeros((1, 14, 3)), np.zeros((1, 15)),
                       np.zeros((1, 11, 3, 3)), np.zeros((1, 11)))


def test_single_person_set_reads_exactly_as_before() -> None:
    """No `<id>_p<k>.txt`: `people` stays empty and every other field is what the reader has
    always given (the truth built from the one skeleton file, track 1)."""
    skeleton = cad60.read_skeleton(FIXTURE / 'data1' / f'{VIDEO_ID}.txt')
    for i, f in enumerate(cad60.read_frames(FIXTURE)):
        assert f.people == ()
        conf = skeleton.joint_conf[i]
        uv = skeleton.pixels()[i]
        t = f.truth
        assert t.names == CAD60_JOINTS and t.track_id == 1 and t.score == 1.0
        assert_array_equal(t.uv, uv)
        assert_array_equal(t.xyz, skeleton.joints_optical()[i])
        assert_array_equal(t.confidence, conf.astype(t.confidence.dtype))
        assert_array_equal(t.source, np.where(conf > 0, DETECTED, MISSING))
        assert f.mask is None and f.video == f'data1/{VIDEO_ID}'
        assert f.key.endswith(f'RGB_{skeleton.frames[i]}.png')


def _add_person(person_dir: Path, k: int, *, shift_mm: float = 700.0,
                hidden_frame: int | None = None) -> cad60.Skeleton:
    """Person k of the fixture's video: person 1 moved `shift_mm` to the right, all
    confidences 0 in `hidden_frame`."""
    s = cad60.read_skeleton(person_dir / f'{VIDEO_ID}.txt')
    conf = np.ones_like(s.joint_conf)
    rot_conf = np.ones_like(s.orientation_conf)
    if hidden_frame is not None:
        conf[hidden_frame] = 0.0
        rot_conf[hidden_frame] = 0.0
    other = cad60.Skeleton(s.frames, s.joints_mm + [shift_mm, 0.0, 0.0], conf,
                           s.orientations, rot_conf)
    cad60.write_skeleton(cad60.person_skeleton_path(person_dir, VIDEO_ID, k), other)
    return other


def test_several_people_read_into_frame_people(person_dir: Path) -> None:
    p2 = _add_person(person_dir, 2, hidden_frame=1)
    p3 = _add_person(person_dir, 3, shift_mm=-700.0)
    video = cad60.list_videos(person_dir)[0]
    assert [p.name for p in video.skeleton_paths()] == \
        [f'{VIDEO_ID}.txt', f'{VIDEO_ID}_p2.txt', f'{VIDEO_ID}_p3.txt']
    frames = list(cad60.read_frames(person_dir))
    single = list(cad60.read_frames(FIXTURE))
    for i, (f, g) in enumerate(zip(frames, single, strict=True)):
        assert [p.track_id for p in f.people] == [1, 2, 3]
        assert f.truth is f.people[0]
        assert_array_equal(f.truth.uv, g.truth.uv)  # person 1 reads as in a one-person set
        assert_allclose(f.people[1].uv, p2.pixels()[i])
        assert_allclose(f.people[2].xyz, p3.joints_optical()[i])
    # person 2 is not seen in frame 2: every joint MISSING
    assert (frames[1].people[1].confidence == 0).all()
    assert (frames[1].people[1].source == MISSING).all()
    assert (frames[0].people[1].confidence == 1).all()


def test_several_people_files_must_agree(person_dir: Path) -> None:
    _add_person(person_dir, 3)
    with pytest.raises(ValueError, match=r'persons \[3\]; expected 2..N without gaps'):
        list(cad60.read_frames(person_dir))
    cad60.person_skeleton_path(person_dir, VIDEO_ID, 3).unlink()
    s = cad60.read_skeleton(person_dir / f'{VIDEO_ID}.txt')
    cad60.write_skeleton(person_dir / f'{VIDEO_ID}_p2.txt', cad60.Skeleton(
        s.frames[:1], s.joints_mm[:1], s.joint_conf[:1], s.orientations[:1],
        s.orientation_conf[:1]))
    with pytest.raises(ValueError, match='_p2.txt: its frame numbers differ'):
        list(cad60.read_frames(person_dir))
    with pytest.raises(ValueError, match='numbered from 1'):
        cad60.person_skeleton_path(person_dir, VIDEO_ID, 0)
