"""MSR Action3D reader (datasets/msraction3d.py) and `pose4d synth --msraction3d`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import J, write_msr
from numpy.testing import assert_allclose

from pose4d_ros.cli.main import main as pose4d_main
from pose4d_ros.datasets import msraction3d as msr
from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS, to_optical
from pose4d_ros.synth import video
from pose4d_ros.synth.takes import select_sources

MSR = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'msraction3d'


def test_joint_order_maps_every_utkinect_joint_once() -> None:
    assert sorted(msr.TO_UTKINECT) == list(range(20))
    assert [msr.MSR_JOINTS[i] for i in msr.TO_UTKINECT] == list(UTKINECT_JOINTS)
    assert msr.MSR_JOINTS[0] == 'left_shoulder' and msr.MSR_JOINTS[19] == 'head'


def test_read_sequence_reorders_drops_zero_frames_and_resamples(tmp_path: Path) -> None:
    sdk = write_msr(tmp_path, 'a05_s07_e02', frames=20, zero=(3, 4))
    seq = msr.read_sequence(tmp_path / 'a05_s07_e02_skeleton3D.txt')
    assert (seq.name, seq.action, seq.subject, seq.take) == ('a05_s07_e02', 5, 7, 2)
    assert seq.action_name == 'forwardPunch'
    assert_allclose(seq.frames, [f for f in range(20) if f not in (3, 4)])
    assert_allclose(seq.joints, sdk[seq.frames], atol=1e-6)  # UTKinect order, Kinect space
    times, joints = msr.resample(seq, fps=30.0)
    assert_allclose(np.diff(times), 1 / 30.0)
    assert len(times) == 2 * 19 + 1  # 15 fps frames 0..19 -> 30 fps frames 0..38
    # every other 30 fps frame is a recorded one; the dropped frames are interpolated
    assert_allclose(joints[::2][[0, 1, 2, 5, 19]], sdk[[0, 1, 2, 5, 19]], atol=1e-6)
    assert_allclose(joints[7], 0.5 * (sdk[3] + sdk[4]), atol=2e-2)


def test_left_and_right_as_utkinect(tmp_path: Path) -> None:
    """The person faces the camera: in the optical frame their left shoulder is at +x."""
    write_msr(tmp_path, 'a01_s01_e01', frames=5)
    seq = msr.read_sequence(tmp_path / 'a01_s01_e01_skeleton3D.txt')
    optical = to_optical(seq.joints)
    assert (optical[:, J['left_shoulder'], 0] > optical[:, J['right_shoulder'], 0]).all()


def _swapped(sdk: np.ndarray, frames, pairs) -> np.ndarray:
    out = sdk.copy()
    for left, right in pairs:
        out[frames, J[left]], out[frames, J[right]] = sdk[frames, J[right]], sdk[frames, J[left]]
    return out


def test_swapped_leg_labels_are_put_back(tmp_path: Path) -> None:
    """Whole legs swapped (knees, ankles, feet on the wrong side of the hips) and shins swapped
    (ankles and feet crossed, knees apart), as the recording's tracker left some files: read
    back as recorded with repair=False, put back by default; legs merely close together or
    crossed by less than the thresholds stay as they are."""
    sdk = write_msr(tmp_path, 'a05_s02_e01', frames=12)
    bad = _swapped(sdk, [2, 3, 4], msr.LEG_PAIRS)
    bad = _swapped(bad, [6, 7], msr.LEG_PAIRS[1:])
    # frame 9: feet a little crossed (a quarter of a hip width), not a swap
    hips = sdk[9, J['left_hip']] - sdk[9, J['right_hip']]
    for name in ('ankle', 'foot'):   # each moved 0.625 hip widths across: 1 -> -0.25
        bad[9, J[f'left_{name}']] -= 0.625 * hips
        bad[9, J[f'right_{name}']] += 0.625 * hips
    assert msr._across(bad, msr.LEG_PAIRS[1])[9] == pytest.approx(-0.25)
    write_msr(tmp_path, 'a05_s02_e01', joints=bad)
    path = tmp_path / 'a05_s02_e01_skeleton3D.txt'
    assert_allclose(msr.read_sequence(path, repair=False).joints, bad, atol=1e-6)
    seq = msr.read_sequence(path)
    assert_allclose(np.delete(seq.joints, 9, axis=0), np.delete(sdk, 9, axis=0), atol=1e-6)
    assert_allclose(seq.joints[9], bad[9], atol=1e-6)
    _, _, legs, shins = msr.repair_legs(bad, np.ones(bad.shape[:2]))
    assert np.flatnonzero(legs).tolist() == [2, 3, 4] and np.flatnonzero(shins).tolist() == [6, 7]


@pytest.mark.parametrize('content, message', [
    ('1 2 3\n' * 20, 'expected 4 fields'),
    ('1 2 3 x\n' * 20, 'non-numeric'),
    ('1 2 3 1\n' * 21, 'not a multiple of 20'),
])
def test_malformed_files_name_the_file(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / 'a02_s03_e01_skeleton3D.txt'
    path.write_text(content)
    with pytest.raises(ValueError, match=message) as info:
        msr.read_sequence(path)
    assert 'a02_s03_e01_skeleton3D.txt' in str(info.value)


def test_bad_name_and_empty_file(tmp_path: Path) -> None:
    bad = tmp_path / 'a21_s01_e01_skeleton3D.txt'
    bad.write_text('')
    with pytest.raises(ValueError, match='a21_s01_e01_skeleton3D.txt: not an MSR'):
        msr.read_sequence(bad)
    empty = tmp_path / 'a01_s01_e01_skeleton3D.txt'
    empty.write_text('')
    assert len(msr.read_sequence(empty).frames) == 0  # the dataset has some: skipped later
    assert video.load_msr_take(empty) is None
    assert msr.pieces(msr.read_sequence(empty)) == []


def test_pieces_split_at_long_gaps(tmp_path: Path) -> None:
    write_msr(tmp_path, 'a13_s02_e02', frames=40, zero=tuple(range(10, 22)))
    seq = msr.read_sequence(tmp_path / 'a13_s02_e02_skeleton3D.txt')
    parts = msr.pieces(seq, max_gap_s=0.5)
    assert [(p.frames[0], p.frames[-1]) for p in parts] == [(0, 9), (22, 39)]
    motion = video.load_msr_take(tmp_path / 'a13_s02_e02_skeleton3D.txt')
    assert motion is not None and len(motion.joints) == 2 * 17 + 1  # the longer piece
    assert motion.actions == {'bend': (0, 34)} and motion.take == video.msr_take_number(13, 2)


def test_action_names_and_numbers() -> None:
    assert msr.action_number('a20') == msr.action_number('pickupthrow') == 20
    assert msr.action_number('7') == 7
    with pytest.raises(ValueError, match='not an MSR Action3D action'):
        msr.action_number('waveHands')


def test_select_sources_split_by_subject_and_action() -> None:
    ms = [f'a{a:02d}_s{s:02d}_e{e:02d}' for a in (1, 2, 13) for s in (1, 7, 8) for e in (1, 2)]
    ut, got = select_sources('s07-s08', 'a01,bend', ['s07_e01', 's01_e01'], ms)
    assert ut == ['s07_e01']
    assert got == ['a01_s07_e01', 'a01_s07_e02', 'a01_s08_e01', 'a01_s08_e02',
                   'a13_s07_e01', 'a13_s07_e02', 'a13_s08_e01', 'a13_s08_e02']
    _, got = select_sources('s07_e01,a02_s08_e02', None, [], ms)
    assert got == ['a01_s07_e01', 'a02_s07_e01', 'a13_s07_e01', 'a02_s08_e02']
    with pytest.raises(ValueError, match='no MSR Action3D sequence for s09'):
        select_sources('s09', None, [], ms)


def test_pose4d_synth_from_msraction3d(tmp_path: Path) -> None:
    src = tmp_path / 'msr'
    for name in ('a01_s07_e01', 'a01_s07_e02', 'a05_s08_e01', 'a05_s01_e01'):
        write_msr(src, name, frames=30)
    (src / 'a05_s08_e02_skeleton3D.txt').write_text('')  # empty: skipped
    out = tmp_path / 'set'
    assert pose4d_main(['synth', '--msraction3d', str(src), '--out', str(out), '--quiet',
                        '--takes', 's07-s08', '--actions', 'a01,forwardPunch', '--frames', '4',
                        '--stride', '3', '--people', '2', '--no-noise', '--occluders', '0']) == 0
    info = json.loads((out / 'synth.json').read_text())
    assert info['takes'] == ['a01_s07_e01', 'a01_s07_e02', 'a05_s08_e01']
    assert info['msraction3d_skipped'] == ['a05_s08_e02']
    assert sorted(v['video'] for v in info['videos']) == [
        'data7/0721000000', 'data7/0722000000', 'data8/0833000000']
    assert {v['activity'] for v in info['videos']} == {'highArmWave', 'forwardPunch'}
    labels = (out / 'data7' / 'activityLabel.txt').read_text()
    assert '0721000000,highArmWave,' in labels
    assert (out / 'data8' / '0833000000_p2.txt').is_file()


@pytest.mark.shared_data
@pytest.mark.skipif(not MSR.is_dir(), reason=f'{MSR} not present')
def test_real_msraction3d_sequences() -> None:
    paths = msr.list_sequences(MSR)
    assert len(paths) > 400
    facing = []
    for path in paths[::20]:
        seq = msr.read_sequence(path)
        if len(seq.frames) == 0:
            continue
        assert np.isfinite(seq.joints).all() and (seq.joints[..., 2] > 0).all()
        p = to_optical(seq.joints)
        across = p[:, J['right_shoulder']] - p[:, J['left_shoulder']]
        up = p[:, J['shoulder_center']] - p[:, J['hip_center']]
        facing.append(np.cross(across, up)[:, 2] > 0)  # the chest faces the camera (-z)...
    # ... as it does in UTKinect with the same convention: labels are the person's own sides
    assert np.mean(np.concatenate(facing)) > 0.9
    motion = video.load_msr_take(MSR / 'a19_s07_e01_skeleton3D.txt')
    assert motion is not None
    feet = motion.joints[:, [J['left_ankle'], J['right_ankle']], 2].min(axis=1)
    assert abs(float(np.median(feet))) < 0.1  # on the fitted floor
    assert 1.3 < float(np.median(motion.joints[:, J['head'], 2])) < 2.0
