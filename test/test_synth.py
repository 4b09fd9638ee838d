"""Synthetic RGB-D renderer: ground truth on the person, determinism, Kinect depth, CAD-60 output.

Poses come from a small synthetic Kinect motion made here (a person facing the camera swinging
the arms), so the tests do not need ../shared/data; one end-to-end test of `pose4d synth` on the
real UTKinect takes runs when that data is present.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from helpers import J, standing_pose, synthetic_take, write_utkinect
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.cli.main import main as pose4d_main
from pose4d_ros.core.camera import cad60_intrinsics, project
from pose4d_ros.core.skeleton import CAD60_JOINTS
from pose4d_ros.datasets import cad60
from pose4d_ros.synth import people as synth_people
from pose4d_ros.synth import render as synth
from pose4d_ros.synth import scene as synth_scene
from pose4d_ros.synth import video as synth_video
from pose4d_ros.synth.kinect import KinectModel, kinect_depth
from pose4d_ros.synth.raycast import projector_shadow

UTKINECT = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'utkinect'
K = cad60_intrinsics()


def in_room(scene: synth_scene.Scene, optical: np.ndarray) -> np.ndarray:
    """Optical-frame points in the scene's room frame (the inverse of `Scene.to_optical`)."""
    return optical @ scene.room_to_cam + scene.cam_pos


def test_retarget_keeps_directions_and_sets_lengths() -> None:
    rng = np.random.default_rng(0)
    body = synth.random_body(rng)
    pose = standing_pose(arm=0.7) + rng.normal(0, 0.02, (20, 3))
    out = synth.retarget(pose, body)
    assert_allclose(out[0], pose[0])
    for i in range(1, 20):
        p = synth.PARENTS[i]
        bone_in, bone_out = pose[i] - pose[p], out[i] - out[p]
        assert_allclose(np.linalg.norm(bone_out), body.bones[i], rtol=1e-9)
        assert_allclose(bone_out / np.linalg.norm(bone_out),
                        bone_in / np.linalg.norm(bone_in), atol=1e-9)
    up = np.array([0.0, -1.0, 0.0])
    grounded = synth.retarget(pose, body, up=up)
    feet = [14, 15, 18, 19]
    assert_allclose((grounded[feet] @ up).min(), (pose[feet] @ up).min(), atol=1e-9)
    with pytest.raises(ValueError, match=r'\(20, 3\)'):
        synth.retarget(pose[:15], body)


@pytest.mark.parametrize('arm', [0.0, 1.2, 2.6])
def test_ground_truth_joints_lie_on_the_person(arm: float) -> None:
    """Head, wrists, hands, ankles and feet project onto the mask and onto valid depth."""
    rng = np.random.default_rng(1)
    body = synth.random_body(rng)
    r = synth.render(standing_pose(arm=arm), body, None, K, rng=rng)
    names = ['head', 'left_wrist', 'right_wrist', 'left_hand', 'right_hand', 'left_ankle',
             'right_ankle', 'left_foot', 'right_foot', 'shoulder_center', 'hip_center']
    uv = np.rint(project(r.joints[[J[n] for n in names]], K)).astype(int)
    for name, (u, v) in zip(names, uv, strict=True):
        assert 0 <= u < K.width and 0 <= v < K.height, name
        assert r.mask[v, u], f'{name} at ({u}, {v}) is not on the person'
        win = r.depth_mm[v - 2:v + 3, u - 2:u + 3].astype(float) / 1000
        z = r.joints[J[name], 2]
        near = win[(win > 0) & (np.abs(win - z) < 0.2)]
        assert near.size > 0, f'no depth reading within 0.2 m of {name}'
    # nothing but the person: depth 0 and black elsewhere
    assert np.all(r.depth_mm[~r.mask] == 0)
    assert 1500 < r.mask.sum() < 15000


def test_ground_truth_in_a_room_without_occluders() -> None:
    rng = np.random.default_rng(2)
    body = synth.random_body(rng)
    for _ in range(3):
        scene = synth_scene.random_scene(rng, K, occluder_prob=0.0)
        room = in_room(scene, standing_pose())
        room[:, :2] += np.array([0.0, 2.8]) - room[0, :2]
        room[:, 2] -= room[[14, 15, 18, 19], 2].min() - body.radii['foot']
        r = synth.render(scene.to_optical(room), body, scene, K, rng=rng)
        for name in ('head', 'left_wrist', 'right_wrist', 'left_ankle', 'right_ankle'):
            u, v = np.rint(project(r.joints[[J[name]]], K)[0]).astype(int)
            if 0 <= u < K.width and 0 <= v < K.height:
                assert r.mask[v, u], name
        # the feet stand on the floor: the lowest foot joint is a shoe's radius up
        up = scene.up_optical
        heights = r.joints[[14, 15, 18, 19]] @ up + scene.cam_height_m
        assert_allclose(heights.min(), body.radii['foot'], atol=1e-6)
        assert r.rgb.dtype == np.uint8 and r.rgb.shape == (240, 320, 3)
        assert (r.depth_mm > 0).mean() > 0.3  # the room is mostly within range


def test_occluder_hides_the_legs_sometimes() -> None:
    """With an occluder in every room, some ankles are hidden (mask False at the joint)."""
    rng = np.random.default_rng(3)
    body = synth.random_body(rng)
    hidden = 0
    for _ in range(6):
        scene = synth_scene.random_scene(rng, K, occluder_prob=1.0)
        assert any(b.kind == 'occluder' for b in scene.boxes)
        room = in_room(scene, standing_pose())
        room[:, :2] += np.array([0.0, 2.6]) - room[0, :2]
        room[:, 2] -= room[[14, 15, 18, 19], 2].min() - body.radii['foot']
        r = synth.render(scene.to_optical(room), body, scene, K, rng=rng)
        u, v = np.rint(project(r.joints[[J['left_ankle']]], K)[0]).astype(int)
        if 0 <= u < K.width and 0 <= v < K.height and not r.mask[v, u]:
            hidden += 1
        assert r.mask[np.rint(project(r.joints[[J['head']]], K)[0, ::-1]).astype(int)[0],
                      np.rint(project(r.joints[[J['head']]], K)[0]).astype(int)[0]]
    assert hidden >= 1


def test_render_is_deterministic_with_a_seed() -> None:
    def once(seed: int) -> synth.Rendered:
        rng = np.random.default_rng(seed)
        body = synth.random_body(rng)
        scene = synth_scene.random_scene(rng, K)
        room = in_room(scene, standing_pose())
        room[:, :2] += np.array([0.0, 3.0]) - room[0, :2]
        return synth.render(scene.to_optical(room), body, scene, K, rng=rng)

    a, b, c = once(7), once(7), once(8)
    assert_array_equal(a.rgb, b.rgb)
    assert_array_equal(a.depth_mm, b.depth_mm)
    assert_array_equal(a.mask, b.mask)
    assert_array_equal(a.joints, b.joints)
    assert not np.array_equal(a.rgb, c.rgb)
    assert not np.array_equal(a.depth_mm, c.depth_mm)


def test_kinect_depth_has_holes_quantisation_and_range() -> None:
    rng = np.random.default_rng(4)
    body = synth.random_body(rng)
    scene = synth_scene.random_scene(rng, K, occluder_prob=0.0)
    room = in_room(scene, standing_pose())
    room[:, :2] += np.array([0.0, 2.8]) - room[0, :2]
    pose = scene.to_optical(room)
    noisy = synth.render(pose, body, scene, K, rng=rng)
    exact = synth.render(pose, body, scene, K, kinect_noise=False)
    assert noisy.depth_mm.dtype == np.uint16
    assert_array_equal(noisy.mask, exact.mask)
    # holes on the person's outline and in the room; exact depth has none within range
    assert (noisy.depth_mm[noisy.mask] == 0).sum() > 10
    in_range = (exact.depth_mm > 500) & (exact.depth_mm < 4400)
    assert np.all(noisy.depth_mm[exact.depth_mm > 4800] == 0)  # beyond range (+- noise)
    assert (noisy.depth_mm[in_range] == 0).mean() > 0.005
    # readings are disparity levels: 1 / (z quant) is close to an integer
    z = noisy.depth_mm[noisy.depth_mm > 0] / 1000.0
    quant = KinectModel().quant
    level = 1.0 / (z * quant)
    mm_rounding = 0.0005 / (z**2 * quant) + 1e-9  # d level / dz times half a millimetre
    assert np.all(np.abs(level - np.rint(level)) <= mm_rounding)


def test_kinect_noise_grows_with_z_squared_as_modelled() -> None:
    """On a wall facing the camera whose depth ramps from 1 to 4.4 m, the error's spread is
    sigma_z(z) = 1.2 mm + 1.9 mm (z - 0.4)^2 combined with the quantisation step q z^2."""
    model = KinectModel(speckle=0.0)
    depth = np.broadcast_to(np.linspace(1.0, 4.4, 320, dtype=np.float32), (240, 320)).copy()
    facing = np.dstack([np.zeros_like(depth)] * 2 + [-np.ones_like(depth)])
    measured = kinect_depth(depth, facing, K, np.random.default_rng(0), model=model)
    for lo, hi in ((1.0, 1.3), (2.4, 2.7), (3.9, 4.2)):
        cols = (depth[0] >= lo) & (depth[0] < hi)
        m = measured[:, cols].astype(float) / 1000
        z = np.broadcast_to(depth[:, cols], m.shape)
        err = (m - z)[m > 0]
        zc = 0.5 * (lo + hi)
        expected = np.hypot(model.noise_a_m + model.noise_b * (zc - 0.4) ** 2,
                            model.quant * zc**2 / np.sqrt(12))
        assert_allclose(err.std(), expected, rtol=0.3)
        assert abs(err.mean()) < 0.3 * expected


def test_projector_shadow_band_left_of_a_near_object() -> None:
    """A box at 2 m in front of a wall at 4 m leaves f b (1/2 - 1/4) ~ 5.3 px with no
    reading on its left, none on its right."""
    depth = np.full((240, 320), 4.0, np.float32)
    depth[:, 150:200] = 2.0
    fb = K.fx * 0.075
    shadow = projector_shadow(depth, fb)
    width = fb * (1 / 2.0 - 1 / 4.0)
    row = shadow[20]
    assert not row[150:].any()
    band = np.flatnonzero(row)
    assert band.max() == 149 and abs(len(band) - width) <= 1.0
    facing = np.dstack([np.zeros_like(depth)] * 2 + [-np.ones_like(depth)])
    z = kinect_depth(depth, facing, K, np.random.default_rng(0),
                     model=KinectModel(speckle=0.0, edge_drop=0.0, edge_ring_drop=0.0))
    assert np.all(z[:, 145:150] == 0) and np.all(z[:, 150:] > 0) and np.all(z[:, :144] > 0)


def test_cad60_ground_truth_tpose_is_identity_and_sides_are_anatomical() -> None:
    pose = standing_pose(arm=np.pi / 2)
    pose[:, 2] = 2.8  # flat, facing the camera
    joints_mm, rots = synth.cad60_ground_truth(pose)
    assert joints_mm.shape == (15, 3) and rots.shape == (11, 3, 3)
    assert_allclose(rots, np.broadcast_to(np.eye(3), rots.shape), atol=0.05)
    assert_allclose(np.einsum('nji,njk->nik', rots, rots), np.broadcast_to(np.eye(3),
                    rots.shape), atol=1e-9)
    # hand := wrist, foot := ankle; anatomical left at larger u (facing person)
    assert_allclose(joints_mm[CAD60_JOINTS.index('left_hand')],
                    pose[J['left_wrist']] * [1000, -1000, 1000])
    assert_allclose(joints_mm[CAD60_JOINTS.index('right_foot')],
                    pose[J['right_ankle']] * [1000, -1000, 1000])
    uv = cad60.project_perspective(joints_mm)
    assert uv[CAD60_JOINTS.index('left_shoulder'), 0] > uv[CAD60_JOINTS.index('right_shoulder'),
                                                           0]


def test_fit_floor_recovers_a_tilted_floor() -> None:
    joints = synthetic_take()
    tilt = np.deg2rad(8.0)  # camera pitched down: rotate the scene up about x
    rot = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt),
                                                                   np.cos(tilt)]])
    tilted = joints @ rot.T
    up, height = synth_video.fit_floor(tilted)
    assert_allclose(up, rot @ [0.0, -1.0, 0.0], atol=2e-3)  # the weak level-camera prior
    feet = tilted[:, [14, 15, 18, 19]]
    assert_allclose((feet @ up + height).min(axis=1), 0.0, atol=5e-3)


def test_pose4d_synth_writes_cad60_that_reads_back(tmp_path: Path) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut)
    out = tmp_path / 'set'
    argv = ['synth', '--utkinect', str(ut), '--out', str(out), '--seed', '3', '--takes',
            's01-s02', '--frames', '4', '--stride', '3', '--videos-per-take', '2', '--quiet']
    assert pose4d_main(argv) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ['set', 'ut']  # no temp dir left
    videos = cad60.list_videos(out)
    assert [v.person for v in videos] == ['data1', 'data1', 'data2', 'data2']
    # s01_e01 is waved in frames 10-100 (window 0), s02_e01 sits in frames 150-180 (window 1)
    assert [v.activity for v in videos] == ['waveHands', 'random', 'random', 'sitDown']
    assert len({v.video_id for v in videos}) == 4
    assert all(len(v.video_id) == 10 and v.video_id.endswith('0003') for v in videos)
    for video in videos:
        skel = cad60.read_skeleton(video.skeleton_path)
        assert_array_equal(skel.frames, [1, 4, 7, 10])
        frames = list(cad60.read_frames(video.person_dir, videos=[video.video_id]))
        for f, uv in zip(frames, skel.pixels(), strict=True):
            assert f.depth_m.shape == (240, 320) and f.color.shape == (240, 320, 3)
            assert f.mask.any() and np.isnan(f.depth_m).any()
            u, v = np.rint(uv[CAD60_JOINTS.index('head')]).astype(int)
            assert f.mask[v, u]
            assert uv[CAD60_JOINTS.index('left_shoulder'), 0] > \
                uv[CAD60_JOINTS.index('right_shoulder'), 0]
    info = json.loads((out / 'synth.json').read_text())
    assert info['seed'] == 3 and len(info['videos']) == 4
    # the same command again gives the same set
    again = tmp_path / 'again'
    argv[4] = str(again)
    assert pose4d_main(argv) == 0
    for video in videos:
        a = video.frame_dir / 'Depth_7.png'
        b = again / video.person / video.video_id / 'Depth_7.png'
        assert a.read_bytes() == b.read_bytes()
        assert (video.frame_dir / 'RGB_7.png').read_bytes() == \
            (b.parent / 'RGB_7.png').read_bytes()


@pytest.mark.parametrize(('extra', 'message'), [
    (['--takes', 's09'], 'no UTKinect take for s09'),
    (['--takes', 's01_x'], 'is not sNN_eMM'),
    (['--frames', '0'], '--frames must be >= 1'),
    (['--occluders', '1.5'], '--occluders must be in'),
    (['--start', '100'], 'beyond the take'),
    (['--actions', 'fly'], 'none of the takes has any of them'),
    (['--turn', '45', '4'], 'turn_deg must be lo <= hi'),
])
def test_pose4d_synth_bad_input_exits_2_and_leaves_nothing(tmp_path: Path, capsys, extra,
                                                           message: str) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut, frames=40)
    out = tmp_path / 'set'
    code = pose4d_main(['synth', '--utkinect', str(ut), '--out', str(out), '--quiet', *extra])
    assert code == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['ut']


def test_pose4d_synth_refuses_existing_out(tmp_path: Path, capsys) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut, frames=40)
    (tmp_path / 'set').mkdir()
    code = pose4d_main(['synth', '--utkinect', str(ut), '--out', str(tmp_path / 'set')])
    assert code == 2 and 'already exists' in capsys.readouterr().err


@pytest.mark.shared_data
@pytest.mark.skipif(not UTKINECT.is_dir(), reason=f'{UTKINECT} not present')
def test_real_utkinect_take_renders_on_the_floor(tmp_path: Path) -> None:
    motion = synth_video.load_takes(UTKINECT, ['s02_e01'])[0]
    plan = synth_video.plan_videos(motion, seed=1, videos=3, frames=3, stride=10)[1]
    job = synth_video.prepare_video(plan, motion, K)
    for _, frame in synth_video.render_video(job):
        uv = np.rint(project(frame.joints[[J['head']]], K)[0]).astype(int)
        assert frame.mask[uv[1], uv[0]]
        heights = frame.joints[[14, 15, 18, 19]] @ job.scene.up_optical + \
            job.scene.cam_height_m
        assert_allclose(heights.min(), job.body.radii['foot'], atol=1e-6)
        assert 1.8 < frame.joints[J['hip_center'], 2] < 4.0


def test_a_sitting_window_gets_a_chair_under_the_hips() -> None:
    rng = np.random.default_rng(5)
    body = synth.random_body(rng)
    scene = synth_scene.random_scene(rng, K, occluder_prob=0.0)
    stand = in_room(scene, standing_pose())
    stand[:, :2] += np.array([0.0, 2.8]) - stand[0, :2]
    sit = stand.copy()
    sit[[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 16], 2] -= 0.35  # the trunk goes down...
    sit[[13, 17], 1] -= 0.4  # ...and the knees come forward (towards the camera, -Y)
    sit[[13, 17], 2] = stand[[13, 17], 2] - 0.1
    room = np.stack([stand, sit])
    same = synth_video._add_seat(scene, room[:1], body, stand[0, 2], rng)
    assert same is scene  # nobody sits: no chair
    seated = synth_video._add_seat(scene, room, body, stand[0, 2], rng)
    new = seated.boxes[len(scene.boxes):]
    assert len(new) == 6  # seat, four legs, backrest
    seat, back = new[0], new[-1]
    assert abs(seat.center[0] - sit[0, 0]) < 0.05
    assert back.center[1] > seat.center[1] + 0.15  # the backrest is behind, away from the knees
    hip = synth.retarget(sit, body, up=np.array([0.0, 0.0, 1.0]))[0, 2]
    assert_allclose(seat.center[2] + seat.half[2], np.clip(hip - 0.015 - 0.9 *
                    body.pelvis_axes[1], 0.3, 0.6), atol=1e-9)


@pytest.mark.parametrize(('stature', 'distance', 'turn'), [(1.4, 1.2, 0.0), (2.0, 4.5, 90.0),
                                                           (1.7, 3.0, 45.0)])
def test_staging_puts_the_body_where_asked(stature: float, distance: float, turn: float) -> None:
    rng = np.random.default_rng(3)
    staging = synth_video.Staging(stature_m=(stature, stature), distance_m=(distance, distance),
                                  turn_deg=(turn, turn))
    body = synth.random_body(rng, stature_m=staging.stature_m)
    assert body.stature_m == stature
    scene = synth_scene.random_scene(rng, K, occluder_prob=0.0, person_zone=staging.person_zone)
    assert max(b.center[1] for b in scene.boxes if b.kind == 'wall') > distance + 0.3
    # a person facing the camera (-Y in the room): the left shoulder on the camera's right (+X)
    floor = np.zeros((2, 20, 3))
    floor[:, :, 2] = 1.0
    floor[:, J['left_shoulder'], 0], floor[:, J['right_shoulder'], 0] = 0.2, -0.2
    placed = synth_video.place_in_room(floor, scene, rng, staging=staging)
    assert_allclose(placed[:, J['hip_center'], 1], distance)
    across = placed[0, J['left_shoulder'], :2] - placed[0, J['right_shoulder'], :2]
    # turned by `turn` degrees: at 90 the right shoulder is the nearer one (right side shown)
    assert_allclose(np.degrees(np.arctan2(across[1], across[0])), turn, atol=1e-6)


@pytest.mark.parametrize(('height', 'pitch'), [(2.4, 30.0), (2.0, 20.0)])
def test_a_mounted_camera_looks_down_from_where_asked(height: float, pitch: float) -> None:
    staging = synth_video.Staging(camera_height_m=(height, height),
                                  camera_pitch_deg=(pitch, pitch))
    scene = synth_scene.random_scene(np.random.default_rng(5), K, occluder_prob=0.0,
                                     mount=staging.mount)
    assert scene.cam_height_m == height
    # the optical axis, in the room (Z up), points down by the pitch (yaw and roll are small)
    axis = scene.room_to_cam[2]
    assert_allclose(np.degrees(np.arcsin(-axis[2])), pitch, atol=0.5)
    # the floor lies the camera's height below it, along the room's up seen from the camera
    floor_point = scene.to_optical(np.array([[0.0, 3.0, 0.0]]))[0]
    assert_allclose(-floor_point @ scene.up_optical, height, atol=1e-6)


@pytest.mark.parametrize('bad', [{'stature_m': (1.9, 1.5)}, {'distance_m': (0.1, 2.0)},
                                 {'turn_deg': (0.0, 200.0)},
                                 {'camera_height_m': (2.0, 2.5)},
                                 {'camera_height_m': (2.0, 4.0), 'camera_pitch_deg': (20, 30)},
                                 {'camera_pitch_deg': (30, 20), 'camera_height_m': (2.0, 2.5)}])
def test_staging_refuses_bad_ranges(bad: dict) -> None:
    with pytest.raises(ValueError, match=next(iter(bad))):
        synth_video.Staging(**bad)


def test_pose4d_synth_staging_options(tmp_path: Path) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut, frames=40)
    out = tmp_path / 'set'
    assert pose4d_main(['synth', '--utkinect', str(ut), '--out', str(out), '--takes', 's01_e01',
                        '--frames', '2', '--stature', '1.8', '1.8', '--distance', '3.5', '3.5',
                        '--turn', '45', '45', '--quiet']) == 0
    info = json.loads((out / 'synth.json').read_text())
    assert info['stature_m'] == [1.8, 1.8] and info['turn_deg'] == [45.0, 45.0]
    video = info['videos'][0]
    assert video['stature_m'] == 1.8 and 3.2 < video['distance_m'] < 3.8
    assert 'camera_pitch_deg' not in info


def test_pose4d_synth_camera_options(tmp_path: Path, capsys) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut, frames=40)
    out = tmp_path / 'set'
    assert pose4d_main(['synth', '--utkinect', str(ut), '--out', str(out), '--takes', 's01_e01',
                        '--frames', '2', '--camera-height', '2.3', '2.3', '--camera-pitch', '28',
                        '28', '--quiet']) == 0
    info = json.loads((out / 'synth.json').read_text())
    assert info['camera_height_m'] == [2.3, 2.3] and info['camera_pitch_deg'] == [28.0, 28.0]
    assert info['videos'][0]['camera_height_m'] == 2.3
    assert pose4d_main(['synth', '--utkinect', str(ut), '--out', str(tmp_path / 'bad'),
                        '--takes', 's01_e01', '--camera-height', '2.3', '2.3', '--quiet']) == 2
    assert 'camera_height_m and camera_pitch_deg go together' in capsys.readouterr().err
    assert not (tmp_path / 'bad').exists()


def _flexion_deg(joints: np.ndarray, side: str) -> np.ndarray:
    upper = joints[:, J[f'{side}_elbow']] - joints[:, J[f'{side}_shoulder']]
    fore = joints[:, J[f'{side}_wrist']] - joints[:, J[f'{side}_elbow']]
    cos = np.sum(upper * fore, axis=1) / np.linalg.norm(upper, axis=1) / \
        np.linalg.norm(fore, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_jitter_arms_moves_only_the_arms_keeping_bones_and_elbow_range() -> None:
    take = synthetic_take(30)
    out = synth_video.jitter_arms(take, np.random.default_rng(5), 60.0)
    arms = [J[f'{s}_{j}'] for s in ('left', 'right') for j in ('elbow', 'wrist', 'hand')]
    others = [i for i in range(20) if i not in arms]
    assert_array_equal(out[:, others], take[:, others])
    assert np.abs(out[:, arms] - take[:, arms]).max() > 0.05  # the arms did move
    for i in arms:
        p = synth.PARENTS[i]
        assert_allclose(np.linalg.norm(out[:, i] - out[:, p], axis=1),
                        np.linalg.norm(take[:, i] - take[:, p], axis=1), atol=1e-9)
    for side in ('left', 'right'):
        flex = _flexion_deg(out, side)
        assert flex.min() >= -1e-6 and flex.max() <= 150.0 + 1e-6
        # smooth: the angles vary linearly over the window, so no jump between frames
        assert np.abs(np.diff(out[:, J[f'{side}_wrist']], axis=0)).max() < 0.1
    again = synth_video.jitter_arms(take, np.random.default_rng(5), 60.0)
    assert_array_equal(again, out)
    with pytest.raises(ValueError, match='arm_jitter_deg'):
        synth_video.Staging(arm_jitter_deg=120.0)


def test_pose4d_synth_arm_jitter_changes_only_the_arms(tmp_path: Path) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut, frames=40)
    sets = {}
    for jitter in ('0', '40'):
        out = tmp_path / f'set{jitter}'
        assert pose4d_main(['synth', '--utkinect', str(ut), '--out', str(out), '--takes',
                            's01_e01', '--frames', '3', '--arm-jitter', jitter, '--quiet']) == 0
        assert json.loads((out / 'synth.json').read_text())['arm_jitter_deg'] == float(jitter)
        (skeleton,) = out.glob('data1/[0-9]*.txt')
        sets[jitter] = cad60.read_skeleton(skeleton).joints_mm
    arms = [CAD60_JOINTS.index(n) for n in CAD60_JOINTS if 'elbow' in n or 'hand' in n]
    rest = [i for i in range(len(CAD60_JOINTS)) if i not in arms]
    assert_allclose(sets['40'][:, rest], sets['0'][:, rest], atol=1e-6)
    assert np.abs(sets['40'][:, arms] - sets['0'][:, arms]).max() > 20.0  # mm


def test_windows_spread_over_the_named_actions(tmp_path: Path) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut)
    motion = synth_video.load_takes(ut, ['s01_e01'])[0]
    a0, b = motion.actions['waveHands']
    plans = synth_video.plan_videos(motion, seed=4, videos=3, frames=5, stride=2,
                                    actions=['waveHands', 'pickUp'])  # s01_e01 never picks up
    assert [p.window for p in plans] == [0, 1, 2]
    assert all(a0 <= p.indices[0] and p.indices[-1] <= b for p in plans)
    assert plans[0].indices[0] == a0 and plans[-1].indices[-1] == b
    assert {p.activity for p in plans} == {'waveHands'}
    assert synth_video.plan_videos(motion, seed=4, actions=['sitDown']) == []


def test_capsule_depth() -> None:
    k = cad60_intrinsics()
    depth = synth.capsule_depth(np.array([[[0.0, -0.2, 2.0], [0.0, 0.2, 2.0]]]),
                                np.array([0.05]), k)
    assert depth.dtype == np.float32
    u = int(round(k.cx))
    assert_allclose(depth[int(round(k.cy)), u], 1.95, atol=0.002)  # the front surface
    assert np.isnan(depth[5, 5])
    width = np.isfinite(depth[int(round(k.cy))]).sum()
    assert abs(width - 2 * k.fx * 0.05 / 2.0) <= 2


# --------------------------------------------------------------------------------------------
# Several people (`pose4d synth --people N`)
# --------------------------------------------------------------------------------------------

def _set_digest(root: Path) -> str:
    """sha256 over every file of a synthetic set but synth.json (which names its paths)."""
    h = hashlib.sha256()
    for p in sorted(root.rglob('*')):
        if p.is_file() and p.name != 'synth.json':
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


# The set below as the renderer wrote it before several people existed (main at ee88e58),
# computed there: one person's output must stay byte for byte what it was.
ONE_PERSON_DIGEST = '6f97d0342a6e3d2d4a0e6d86eec5d0710066c11ab4a32b525e40152b009a0770'


@pytest.mark.parametrize('extra', [[], ['--people', '1']])
def test_one_person_output_is_byte_for_byte_as_before(tmp_path: Path, extra: list[str]) -> None:
    write_utkinect(tmp_path / 'ut')
    out = tmp_path / 'set'
    assert pose4d_main(['synth', '--utkinect', str(tmp_path / 'ut'), '--out', str(out),
                        '--seed', '4', '--takes', 's01-s02', '--frames', '3', '--stride', '5',
                        '--quiet', *extra]) == 0
    assert not list(out.rglob('*_p*.txt')) and not list(out.rglob('People_*.png'))
    info = json.loads((out / 'synth.json').read_text())
    assert 'people' not in info and 'people' not in info['videos'][0]
    assert _set_digest(out) == ONE_PERSON_DIGEST


def _poses_side_by_side() -> list[np.ndarray]:
    """Two people facing the camera: person 1 at 2.5 m, person 2 at 3.5 m half hidden behind."""
    return [standing_pose(z=2.5, arm=0.4), standing_pose(z=3.5, arm=1.2) + [0.25, 0.0, 0.0]]


def test_render_people_shows_the_nearest_surface_in_depth_and_colour() -> None:
    poses = _poses_side_by_side()
    bodies = [synth.random_body(np.random.default_rng(s)) for s in (1, 2)]
    both = synth.render_people(poses, bodies, None, K, kinect_noise=False)
    alone = [synth.render(p, b, None, K, kinect_noise=False) for p, b in zip(poses, bodies,
                                                                             strict=True)]
    d1, d2 = (a.depth_mm.astype(float) for a in alone)
    d1[d1 == 0], d2[d2 == 0] = np.inf, np.inf
    overlap = np.isfinite(d1) & np.isfinite(d2)
    assert overlap.sum() > 500  # the test is about the overlap: there must be one
    # the ray caster keeps the nearest surface over both bodies: person 1 (nearer) wins there
    expected = np.where(d1 <= d2, 1, 2) * (np.isfinite(d1) | np.isfinite(d2))
    assert_array_equal(both.labels, expected)
    assert_array_equal(both.mask, expected > 0)
    assert (both.labels[overlap] == 1).all()
    assert_array_equal(both.depth_mm, np.where(np.isfinite(np.minimum(d1, d2)),
                                               np.minimum(d1, d2), 0).astype(np.uint16))
    # colour: each pixel is its own person's, as that person renders alone
    for k, a in enumerate(alone, start=1):
        assert_array_equal(both.rgb[both.labels == k], a.rgb[both.labels == k])
    assert_allclose(both.joints[0], alone[0].joints)
    assert_array_equal(both.visible_px(), [(expected == 1).sum(), (expected == 2).sum()])
    # one person through render_people is render itself
    one = synth.render_people(poses[:1], bodies[:1], None, K, kinect_noise=True,
                              rng=np.random.default_rng(5))
    ref = synth.render(poses[0], bodies[0], None, K, rng=np.random.default_rng(5))
    assert_array_equal(one.rgb, ref.rgb)
    assert_array_equal(one.depth_mm, ref.depth_mm)


@pytest.mark.parametrize('people', [2, 3])
def test_pose4d_synth_people_writes_every_persons_truth(tmp_path: Path, people: int) -> None:
    ut = tmp_path / 'ut'
    write_utkinect(ut)
    out = tmp_path / 'set'
    assert pose4d_main(['synth', '--utkinect', str(ut), '--out', str(out), '--seed', '2',
                        '--takes', 's01-s02', '--frames', '4', '--stride', '3', '--people',
                        str(people), '--crossing', '0.5', '--no-noise', '--quiet']) == 0
    info = json.loads((out / 'synth.json').read_text())
    assert info['people'] == people and info['crossing'] == 0.5
    assert [v['crossing'] for v in info['videos']].count(True) == 1  # round(0.5 x 2 videos)
    videos = cad60.list_videos(out)
    assert len(videos) == 2
    for video, record in zip(videos, info['videos'], strict=True):
        paths = video.skeleton_paths()
        assert [p.name for p in paths] == [f'{video.video_id}.txt'] + [
            f'{video.video_id}_p{k}.txt' for k in range(2, people + 1)]
        # other takes first: person 2 is the other subject's take
        takes = [p['take'] for p in record['people']]
        assert takes[0] == f's0{video.person[-1]}_e01' and takes[1] != takes[0]
        assert len({p['stature_m'] for p in record['people']}) == people  # other bodies
        distances = [p['distance_m'] for p in record['people']]
        assert len(set(distances)) == people
        frames = list(cad60.read_frames(video.person_dir, videos=[video.video_id]))
        assert len(frames) == 4
        skeletons = [cad60.read_skeleton(p) for p in paths]
        for i, f in enumerate(frames):
            assert [p.track_id for p in f.people] == list(range(1, people + 1))
            assert f.truth is f.people[0]
            labels = cad60.load_people(cad60.people_path(video.frame_dir, 1 + 3 * i))
            assert set(np.unique(labels)) <= set(range(people + 1))
            assert_array_equal(f.mask, labels > 0)  # the mask: every person's pixels
            for k, (truth, skel) in enumerate(zip(f.people, skeletons, strict=True), start=1):
                assert_allclose(truth.uv, skel.pixels()[i])
                seen = (labels == k).sum() >= synth_video.MIN_SEEN_PX
                assert_array_equal(truth.confidence, 1.0 if seen else 0.0)
                if seen:
                    # its pixels lie at its own depth (exact depth: --no-noise)
                    z = np.nanmedian(f.depth_m[labels == k])
                    assert abs(z - truth.xyz[cad60_torso(), 2]) < 0.35
        # the people stand at the distances synth.json gives (depth order: see
        # test_render_people_shows_the_nearest_surface_in_depth_and_colour)
        by_z = np.argsort([f.people[k].xyz[cad60_torso(), 2] for k in range(people)])
        assert by_z.tolist() == np.argsort(distances).tolist()


def cad60_torso() -> int:
    return CAD60_JOINTS.index('torso')


@pytest.mark.parametrize(('extra', 'message'), [
    (['--people', '0'], '--people must be 1, 2 or 3, got 0'),
    (['--people', '4'], '--people must be 1, 2 or 3, got 4'),
    (['--people', '-2'], '--people must be 1, 2 or 3, got -2'),
    (['--crossing', '0.5'], '--crossing needs --people 2 or 3'),
    (['--people', '2', '--crossing', '1.5'], '--crossing must be a fraction in [0, 1]'),
])
def test_pose4d_synth_refuses_bad_people(tmp_path: Path, capsys, extra: list[str],
                                         message: str) -> None:
    write_utkinect(tmp_path / 'ut', frames=40)
    code = pose4d_main(['synth', '--utkinect', str(tmp_path / 'ut'), '--out',
                        str(tmp_path / 'set'), '--quiet', *extra])
    assert code == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['ut']


def test_crossing_person_passes_in_front_of_the_other() -> None:
    """A crossing puts the nearer person on the far one's other side by the end, passing in
    line with it; without a crossing both keep their sides."""
    scene = synth_scene.random_scene(np.random.default_rng(0), K, occluder_prob=0.0,
                                     person_zone=synth_people.people_zone(
                                         synth_video.Staging(distance_m=(2.5, 4.0))))
    standing = in_room(scene, standing_pose(z=3.0, cam_height=scene.cam_height_m))
    still = [np.repeat(standing[None], 60, axis=0)] * 2
    staging = synth_video.Staging(distance_m=(2.5, 4.0), turn_deg=(0.0, 0.0))
    for seed in range(4):
        for crossing in (False, True):
            placed = synth_people.place_people(still, scene, np.random.default_rng(seed),
                                               staging=staging, crossing=crossing)
            hips = np.array([p[:, J['hip_center']] for p in placed])  # (2, F, 3) room
            near = int(np.argmin(hips[:, 0, 1]))
            far = 1 - near
            assert hips[far, 0, 1] - hips[near, 0, 1] > (1.0 if crossing else 0.2)
            # bearing of the near person relative to the far one (room X / Y ~ image column)
            side = hips[near, :, 0] / hips[near, :, 1] - hips[far, :, 0] / hips[far, :, 1]
            apart = np.abs(hips[0, :, 0] - hips[1, :, 0])
            if crossing:
                assert np.sign(side[0]) != np.sign(side[-1])
                assert np.abs(side).min() < 0.02
            else:
                assert np.sign(side[0]) == np.sign(side[-1])
                assert 1.0 <= apart[0] <= 4.0
