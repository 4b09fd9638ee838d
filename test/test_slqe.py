"""SLQE tracker (core.slqe): model matrices, gating, coasting, resets, interface."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pose4d_ros.core.skeleton import PARTS_10, PartTree
from pose4d_ros.core.slqe import (
    REFERENCE_SCALE_PX,
    ConstantVelocityTracker,
    CvConfig,
    SlqeConfig,
    SlqeTracker,
    Source,
    TrackOutput,
    axis_process_noise,
    axis_transition,
    coupling_at,
    initial_state,
    output,
    predict,
    process_noise_matrix,
    transition_matrix,
    update,
)

CHAIN = PartTree(('a', 'b', 'c'), (-1, 0, 1))
FPS = 30.0


def linear_tracks(rng: np.random.Generator, n: int = 240, *, accel: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(T,) times and (T, 10, 2) clean pixel tracks at constant velocity/acceleration.

    Like a body: a common motion of all parts plus a small motion of each part.
    """
    t = np.arange(n) / FPS
    start = rng.uniform(60, 260, (10, 2))
    vel = rng.uniform(-40, 40, 2) + rng.uniform(-8, 8, (10, 2))
    acc = rng.uniform(-20, 20, 2) + rng.uniform(-4, 4, (10, 2)) if accel else np.zeros((10, 2))
    uv = start + vel * t[:, None, None] + 0.5 * acc * t[:, None, None] ** 2
    return t, uv


def run(tracker: SlqeTracker, times: np.ndarray, uv: np.ndarray,
        conf: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    pos, src = [], []
    for k, stamp in enumerate(times):
        out = tracker.step(uv[k], None if conf is None else conf[k], stamp)
        pos.append(out.positions)
        src.append(out.source)
    return np.array(pos), np.array(src)


def err(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=-1)


# --- model matrices -------------------------------------------------------------------------


def test_transition_has_tree_block_structure() -> None:
    """A for a 3-part chain: own blocks on the diagonal, A2 at (child, parent) only."""
    cfg = SlqeConfig(order=3, coupling=0.3)
    dt = 1.0 / FPS
    a = transition_matrix(dt, cfg, CHAIN)
    assert a.shape == (18, 18)
    f = axis_transition(dt, 3, cfg.accel_time_s)
    k = coupling_at(dt, 0.3)
    assert_allclose(k, 0.3)
    blk = {(i, j): a[6 * i:6 * i + 6, 6 * j:6 * j + 6] for i in range(3) for j in range(3)}
    assert_allclose(blk[0, 0], np.kron(f, np.eye(2)))  # the root: plain kinematics (A1)
    a1 = np.kron(f * np.array([1.0, 1 - k, 1 - k]), np.eye(2))
    a2 = np.kron(f * np.array([0.0, k, k]), np.eye(2))
    for child, parent in ((1, 0), (2, 1)):
        assert_allclose(blk[child, child], a1)
        assert_allclose(blk[child, parent], a2)
    for i, j in ((0, 1), (0, 2), (1, 2), (2, 0)):
        assert not blk[i, j].any(), (i, j)
    # No coupling: block diagonal.
    a0 = transition_matrix(dt, SlqeConfig(coupling=0.0), CHAIN)
    assert_allclose(a0, np.kron(np.eye(3), np.kron(f, np.eye(2))))


def test_coupling_keeps_common_motion() -> None:
    """Parts moving together are predicted as without coupling; a child follows its parent."""
    cfg = SlqeConfig(coupling=0.4)
    dt = 0.05
    s = np.array([10, 20, 30, -5, 2, 1] * 3, float)
    s[6:8] = [50, 60]  # positions differ, motion is common
    s[12:14] = [80, 90]
    a = transition_matrix(dt, cfg, CHAIN)
    a0 = transition_matrix(dt, SlqeConfig(coupling=0.0), CHAIN)
    assert_allclose(a @ s, a0 @ s)
    # A still child pulled towards its moving parent.
    s2 = s.copy()
    s2[8:12] = 0.0
    nxt = a @ s2
    assert nxt[8] > 0 and nxt[9] < 0  # velocity picks up the parent's sign
    assert nxt[6] > 50  # and the position moves with it


def test_irregular_dt_composes() -> None:
    """F(a) F(b) = F(a + b) and Q(a + b) = F(b) Q(a) F(b)^T + Q(b): dt from stamps is exact."""
    for order in (2, 3):
        fa, fb = axis_transition(0.03, order), axis_transition(0.11, order)
        assert_allclose(fb @ fa, axis_transition(0.14, order), atol=1e-12)
        qa, qb = axis_process_noise(0.03, order, 7.0), axis_process_noise(0.11, order, 7.0)
        assert_allclose(fb @ qa @ fb.T + qb, axis_process_noise(0.14, order, 7.0), rtol=1e-9)
    assert_allclose(coupling_at(0.1, 0.2), 1 - 0.8 ** 3)


def test_singer_acceleration_decays_and_composes() -> None:
    """With `accel_time_s` the acceleration decays as exp(-dt / tau), integrated exactly into
    velocity and position (so irregular steps still compose); a long time constant is the
    paper's constant acceleration."""
    tau = 0.2
    fa, fb = axis_transition(0.03, 3, tau), axis_transition(0.11, 3, tau)
    assert_allclose(fb @ fa, axis_transition(0.14, 3, tau), atol=1e-12)
    s = axis_transition(0.1, 3, tau) @ np.array([0.0, 0.0, 100.0])
    assert_allclose(s[2], 100.0 * math.exp(-0.5))
    assert_allclose(s[1], 100.0 * tau * (1 - math.exp(-0.5)))  # the integral of a(t)
    assert 0 < s[0] < 0.5 * 100.0 * 0.1 ** 2
    assert_allclose(axis_transition(0.1, 3, 1e6), axis_transition(0.1, 3), atol=1e-6)
    assert_allclose(axis_transition(0.1, 2, tau), axis_transition(0.1, 2))  # order 2: no-op


def test_process_noise_is_block_diagonal_psd() -> None:
    q = process_noise_matrix(0.04, SlqeConfig(), 3)
    assert q.shape == (18, 18)
    assert not q[:6, 6:].any()
    assert np.linalg.eigvalsh(q).min() > -1e-12


def test_predict_update_do_not_mutate() -> None:
    cfg = SlqeConfig()
    state = initial_state(3, cfg)
    z = np.array([[10.0, 20.0], [30.0, np.nan], [50.0, 60.0]])
    z_copy = z.copy()
    s1, _ = update(state, z, None, cfg, CHAIN)
    assert not state.active.any() and not state.x.any()
    x_before, cov_before = s1.x.copy(), s1.cov.copy()
    s2 = predict(s1, 0.1, cfg, CHAIN)
    s3, _ = update(s2, z + 1.0, np.ones(3), cfg, CHAIN)
    assert_allclose(s1.x, x_before)
    assert_allclose(s1.cov, cov_before)
    assert_allclose(z, z_copy)
    assert s3 is not s2


# --- tracking behaviour ---------------------------------------------------------------------


@pytest.mark.parametrize('accel', [False, True])
@pytest.mark.parametrize('make', [
    lambda: SlqeTracker(SlqeConfig(), PARTS_10),
    lambda: ConstantVelocityTracker(CvConfig(), PARTS_10),
], ids=['slqe', 'cv'])
def test_filter_reduces_noise(accel: bool, make) -> None:
    rng = np.random.default_rng(0)
    t, truth = linear_tracks(rng, accel=accel)
    noisy = truth + rng.normal(0, 3.0, truth.shape)
    pos, src = run(make(), t, noisy)
    raw = err(noisy, truth)[30:].mean()
    filt = err(pos, truth)[30:].mean()
    assert (src == Source.DETECTED).mean() > 0.98  # a 99.9 % gate rejects few true detections
    assert filt < 0.8 * raw, (filt, raw)


def test_outlier_is_rejected() -> None:
    rng = np.random.default_rng(0)
    t, truth = linear_tracks(rng, 90)
    noisy = truth + rng.normal(0, 2.0, truth.shape)
    noisy[60, 3] += [35.0, -25.0]  # a wrist detection jumps 43 px away
    tracker = SlqeTracker(SlqeConfig(), PARTS_10)
    pos, src = run(tracker, t, noisy)
    assert src[60, 3] == Source.TRACKED
    assert (np.delete(src[60], 3) == Source.DETECTED).all()
    assert err(pos[60, 3], truth[60, 3]) < 6.0
    # Without the gate the same outlier drags the estimate far away.
    pos0, _ = run(SlqeTracker(SlqeConfig(gate_chi2=math.inf), PARTS_10), t, noisy)
    assert err(pos0[60, 3], truth[60, 3]) > 3 * err(pos[60, 3], truth[60, 3])


def test_coasts_through_dropouts() -> None:
    rng = np.random.default_rng(0)
    t, truth = linear_tracks(rng, 120)
    noisy = truth + rng.normal(0, 2.0, truth.shape)
    noisy[70:80, 5] = np.nan  # ten frames without the right wrist
    noisy[75, :] = np.nan  # and one frame without anything
    cfg = SlqeConfig()
    tracker = SlqeTracker(cfg, PARTS_10)
    pos, src = run(tracker, t, noisy)
    assert (src[70:80, 5] == Source.TRACKED).all()
    assert (src[75] == Source.TRACKED).all()
    assert np.isfinite(pos[70:80, 5]).all()
    assert err(pos[70:80, 5], truth[70:80, 5]).max() < 8.0
    assert src[80, 5] == Source.DETECTED


def test_covariance_grows_while_coasting() -> None:
    tracker = SlqeTracker(SlqeConfig(), PARTS_10)
    rng = np.random.default_rng(0)
    t, truth = linear_tracks(rng, 60)
    for k in range(40):
        tracker.step(truth[k], None, t[k])
    traces = []
    for k in range(40, 50):
        out = tracker.step(np.full((10, 2), np.nan), None, t[k])
        traces.append(np.trace(out.covariances[4]))
        assert_allclose(out.covariances, np.swapaxes(out.covariances, 1, 2))
        assert out.confidence[4] < 1.0
    assert np.all(np.diff(traces) > 0)


def test_lost_track_is_dropped_then_restarts() -> None:
    cfg = SlqeConfig(max_missed_frames=5)
    tracker = SlqeTracker(cfg, PARTS_10)
    rng = np.random.default_rng(0)
    t, truth = linear_tracks(rng, 40)
    for k in range(10):
        tracker.step(truth[k], None, t[k])
    gone = truth.copy()
    gone[:, 1] = np.nan
    srcs = [tracker.step(gone[k], None, t[k]).source[1] for k in range(10, 17)]
    assert srcs[:5] == [Source.TRACKED] * 5
    assert srcs[5:] == [Source.MISSING] * 2
    out = tracker.step(gone[17], None, t[17])
    assert np.isnan(out.positions[1]).all() and out.confidence[1] == 0
    assert np.isnan(out.covariances[1]).all()
    # Detected again far away: restarts there.
    z = truth[18].copy()
    z[1] += 100.0
    out = tracker.step(z, None, t[18])
    assert out.source[1] == Source.DETECTED
    assert_allclose(out.positions[1], z[1])


def test_drifted_filter_yields_to_consistent_detections() -> None:
    """A part that really jumped (consistent detections far from the prediction) is re-acquired."""
    cfg = SlqeConfig(drift_frames=3)
    tracker = SlqeTracker(cfg, PARTS_10)
    rng = np.random.default_rng(0)
    t, truth = linear_tracks(rng, 60)
    truth[30:, 7] += [60.0, 0.0]
    srcs, pos = [], []
    for k in range(60):
        out = tracker.step(truth[k] + rng.normal(0, 1.0, (10, 2)), None, t[k])
        srcs.append(out.source[7])
        pos.append(out.positions[7])
    assert srcs[30:32] == [Source.TRACKED] * 2
    assert srcs[32] == Source.DETECTED
    assert err(np.array(pos[40:]), truth[40:, 7]).max() < 5.0


# A stiffer filter than the default (the process noise tuned on corrupted real motion, before
# real cameras asked for more): the rules below exist for the frames where the prediction
# rejects what really happened, and at the default these sudden changes of motion fall within
# its gate more often (nothing to show)
STIFF = 300.0


@pytest.mark.parametrize('stop', [True, False])
def test_a_body_that_stops_dead_is_followed_at_once(stop: bool) -> None:
    """A body moving 16 px a frame stops: the prediction overshoots the detections at rest
    beyond the gate; with the stop hypothesis they restart the parts where they stopped,
    without it the filter coasts on past them for two frames."""
    rng = np.random.default_rng(1)
    t = np.arange(40) / FPS
    truth = np.tile(rng.uniform(100, 200, (10, 2)), (40, 1, 1))
    truth[:30, :, 0] += (16.0 * np.arange(30) - 16.0 * 29)[:, None]
    tracker = SlqeTracker(SlqeConfig(stop_hypothesis=stop, process_noise=STIFF), PARTS_10)
    pos, src = run(tracker, t, truth + rng.normal(0, 1.0, truth.shape))
    assert (src[:30] == Source.DETECTED).all()  # the motion itself is followed
    if stop:
        assert (src[30:] == Source.DETECTED).all()
        assert err(pos[30:], truth[30:]).max() < 15.0
    else:
        assert (src[30:32, 3] == Source.TRACKED).all()
        assert err(pos[31, 3], truth[31, 3]) > 20.0


@pytest.mark.parametrize('shadow', [5, 0])
def test_a_restart_on_wrong_detections_is_undone(shadow: int) -> None:
    """Three detections of a wrist agree on a wrong place 40 px away, so the filter restarts
    there (it cannot tell a drift from a stuck detector); when the right detections come back,
    the track kept from before the restart takes them at once instead of rejecting them as
    outliers of the wrong track."""
    rng = np.random.default_rng(2)
    t, truth = linear_tracks(rng, 60)
    noisy = truth + rng.normal(0, 1.0, truth.shape)
    noisy[30:33, 3] += [40.0, 0.0]
    # (the limb rule off: it would take the wrong place a frame sooner, the shoulder-wrist
    # distance of these random parts being kept within its tolerance)
    tracker = SlqeTracker(SlqeConfig(shadow_frames=shadow, limb_tolerance=0.0), PARTS_10)
    pos, src = run(tracker, t, noisy)
    assert (src[30:32, 3] == Source.TRACKED).all() and src[32, 3] == Source.DETECTED
    assert err(pos[32, 3], truth[32, 3]) > 30.0  # followed the wrong place
    if shadow:
        assert (src[33:, 3] == Source.DETECTED).all()
        assert err(pos[33:, 3], truth[33:, 3]).max() < 8.0
    else:
        assert src[33, 3] == Source.TRACKED and err(pos[33, 3], truth[33, 3]) > 20.0


ARM = PartTree(('neck', 'right_elbow', 'right_wrist'), (-1, 0, 1))


def swung_wrist(start: int, n: int = 40, step_rad: float = 0.55) -> np.ndarray:
    """(n, 3, 2) pixels: neck and elbow at rest, the wrist 30 px from the elbow, at rest until
    frame `start`, then whipped round the elbow at `step_rad` a frame (16 px a frame)."""
    angle = step_rad * np.clip(np.arange(n) - start + 1, 0, None)
    uv = np.empty((n, 3, 2))
    uv[:, 0] = [160.0, 60.0]
    uv[:, 1] = [160.0, 120.0]
    uv[:, 2] = uv[:, 1] + 30.0 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    return uv


@pytest.mark.parametrize('tolerance', [0.35, 0.0])
def test_a_hand_whipped_round_its_elbow_is_followed(tolerance: float) -> None:
    """A wrist at rest starts turning round its elbow at 16 px a frame: the prediction loses it
    and the consecutive detections, 16 px apart, never agree as a drift; with the limb rule the
    second rejected detection, still 30 px from the accepted elbow's, restarts the wrist."""
    t = np.arange(40) / FPS
    truth = swung_wrist(20)
    tracker = SlqeTracker(SlqeConfig(limb_tolerance=tolerance, process_noise=STIFF), ARM)
    pos, src = run(tracker, t, truth + np.random.default_rng(3).normal(0, 0.5, truth.shape))
    assert (src[:, :2] == Source.DETECTED).all()
    assert src[20, 2] == Source.TRACKED  # the first frame of the swing is an outlier to it
    if tolerance:
        assert src[21, 2] == Source.DETECTED
        assert err(pos[21:25, 2], truth[21:25, 2]).max() < 12.0
    else:
        assert (src[21:25, 2] == Source.TRACKED).all()
        assert err(pos[24, 2], truth[24, 2]) > 30.0


def test_the_limb_rule_takes_no_detection_off_the_limb() -> None:
    """Two detections in a row 30 px off the wrist, 60 px from the elbow (the limb is 30 px
    long), stay outliers."""
    t = np.arange(30) / FPS
    truth = swung_wrist(100, 30)
    noisy = truth + np.random.default_rng(4).normal(0, 0.5, truth.shape)
    noisy[20:22, 2] += [30.0, 0.0]
    pos, src = run(SlqeTracker(SlqeConfig(), ARM), t, noisy)
    assert (src[20:22, 2] == Source.TRACKED).all()
    assert err(pos[20:, 2], truth[20:, 2]).max() < 5.0


def test_reset_and_time_going_back() -> None:
    tracker = SlqeTracker(SlqeConfig(), PARTS_10)
    z = np.tile([[100.0, 100.0]], (10, 1))
    tracker.step(z, None, 1.0)
    tracker.step(z, None, 1.033)
    tracker.reset()
    assert not tracker.state.active.any() and tracker.state.stamp is None
    tracker.step(z, None, 5.0)
    out = tracker.step(z + 50, None, 4.0)  # a looped bag: starts again on the detections
    assert (out.source == Source.DETECTED).all()
    assert_allclose(out.positions, z + 50)
    out = tracker.step(z, None, 6.0)  # a gap over max_dt_s: starts again too
    assert_allclose(out.positions, z)


def test_low_confidence_moves_the_estimate_less() -> None:
    def moved(conf: float) -> float:
        tracker = SlqeTracker(SlqeConfig(gate_chi2=math.inf), PARTS_10)
        z = np.tile([[100.0, 100.0]], (10, 1))
        for k in range(20):
            tracker.step(z, None, k / FPS)
        out = tracker.step(z + [6.0, 0.0], np.full(10, conf), 20 / FPS)
        return float(out.positions[0, 0] - 100.0)

    assert 0 < moved(0.1) < 0.5 * moved(1.0)


def test_detection_output_mode_returns_the_detection() -> None:
    cfg = SlqeConfig(output='detection')
    tracker = SlqeTracker(cfg, PARTS_10)
    rng = np.random.default_rng(0)
    t, truth = linear_tracks(rng, 30)
    noisy = truth + rng.normal(0, 2.0, truth.shape)
    for k in range(30):
        out = tracker.step(noisy[k], None, t[k])
    assert_allclose(out.positions, noisy[29])
    assert_allclose(out.covariances[:, 0, 0], cfg.measurement_noise_px ** 2)


@pytest.mark.parametrize('uv, conf, stamp', [
    (np.zeros((9, 2)), None, 0.0),
    (np.zeros((10, 3)), None, 0.0),
    (np.zeros((10, 2)), np.full(10, 1.5), 0.0),
    (np.zeros((10, 2)), np.ones(9), 0.0),
    (np.zeros((10, 2)), None, math.nan),
])
def test_bad_input_is_refused(uv, conf, stamp) -> None:
    with pytest.raises(ValueError):
        SlqeTracker(SlqeConfig(), PARTS_10).step(uv, conf, stamp)


@pytest.mark.parametrize('kwargs', [
    {'order': 4}, {'coupling': 1.0}, {'coupling': -0.1}, {'process_noise': 0.0},
    {'gate_chi2': -1.0}, {'output': 'best'}, {'confidence_decay': 0.0},
    {'accel_time_s': 0.0}, {'shadow_frames': -1}, {'limb_tolerance': 1.0},
    {'limb_tolerance': -0.1},
])
def test_bad_config_is_refused(kwargs) -> None:
    with pytest.raises(ValueError):
        SlqeConfig(**kwargs)


def test_output_shapes_and_missing_parts() -> None:
    tracker = ConstantVelocityTracker(CvConfig(), PARTS_10)
    z = np.tile([[100.0, 120.0]], (10, 1))
    z[2] = np.nan
    out = tracker.step(z, np.where(np.isnan(z[:, 0]), np.nan, 0.8), 0.0)
    assert out.positions.shape == (10, 2) and out.covariances.shape == (10, 2, 2)
    assert out.velocities.shape == (10, 2)
    assert out.source.dtype == np.uint8 and out.confidence.dtype == np.float32
    assert out.source[2] == Source.MISSING and np.isnan(out.positions[2]).all()
    assert_allclose(out.confidence[[0, 1, 3]], 0.8)
    valid = out.source != Source.MISSING
    assert np.isfinite(out.positions[valid]).all()


def test_irregular_stamps() -> None:
    """Frame intervals of 1-8 frames at 30 fps: still filtered, and a real jump re-acquired."""
    rng = np.random.default_rng(6)
    steps = rng.choice([1, 2, 4, 8], 150) / FPS
    t = np.concatenate([[0.0], np.cumsum(steps)])
    start = rng.uniform(60, 260, (10, 2))
    vel = rng.uniform(-30, 30, 2) + rng.uniform(-5, 5, (10, 2))
    truth = start + vel * t[:, None, None]
    truth[100:, 3] += [0.0, 80.0]  # the left wrist really jumps
    noisy = truth + rng.normal(0, 3.0, truth.shape)
    pos, src = run(SlqeTracker(SlqeConfig(), PARTS_10), t, noisy)
    keep = np.ones(len(t), bool)
    keep[:20] = keep[100:104] = False
    assert err(pos, truth)[keep].mean() < 0.85 * err(noisy, truth)[keep].mean()
    assert (src[104:, 3] == Source.DETECTED).mean() > 0.9
    assert err(pos[110:, 3], truth[110:, 3]).max() < 10.0


# --- person scale ---------------------------------------------------------------------------


def test_filter_is_the_same_in_units_of_the_person() -> None:
    """The same motion seen twice as large (a person half as far, or a camera of twice the
    resolution) with twice the person scale gives twice the estimates and the same choices:
    gating, drift re-initialisation and coasting do not depend on the image's size."""
    rng = np.random.default_rng(5)
    times, uv = linear_tracks(rng, accel=True)
    noisy = uv + rng.normal(0, 3, uv.shape)
    outliers = rng.random(uv.shape[:2]) < 0.1
    noisy[outliers] += rng.uniform(20, 60, (int(outliers.sum()), 2))
    noisy[rng.random(uv.shape[:2]) < 0.05] = np.nan
    outs = []
    for factor in (1.0, 2.0):
        tracker = SlqeTracker(SlqeConfig(), PARTS_10)
        pos, src = [], []
        for k, stamp in enumerate(times):
            out = tracker.step(factor * noisy[k], None, stamp, scale_px=factor * 37.0)
            pos.append(out.positions / factor)
            src.append(out.source)
        outs.append((np.array(pos), np.array(src)))
    assert (outs[0][1] == outs[1][1]).all()
    assert (outs[0][1] == Source.TRACKED).any()   # some detections were rejected
    assert_allclose(outs[0][0], outs[1][0], rtol=0, atol=1e-6)
    # without the scale the doubled motion is filtered differently (the test can fail)
    tracker = SlqeTracker(SlqeConfig(), PARTS_10)
    plain = [tracker.step(2.0 * noisy[k], None, stamp).source for k, stamp in enumerate(times)]
    assert (np.array(plain) != outs[0][1]).any()


def test_scale_px_must_be_positive() -> None:
    tracker = SlqeTracker(SlqeConfig(), PARTS_10)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match='scale_px'):
            tracker.step(np.zeros((10, 2)), None, 0.0, scale_px=bad)


# --- the compiled step ----------------------------------------------------------------------

def _python_step(tracker: SlqeTracker, uv: np.ndarray, conf: np.ndarray | None, stamp: float,
                 scale_px: float | None) -> TrackOutput:
    """`SlqeTracker.step` by the Python functions (`predict`, `update`, `output`)."""
    gain = 1.0 if scale_px is None else scale_px / REFERENCE_SCALE_PX
    last = tracker.state.stamp
    if last is not None and not 0.0 <= stamp - last <= tracker.config.max_dt_s:
        tracker.reset()
        last = None
    state = predict(tracker.state, 0.0 if last is None else stamp - last, tracker.config,
                    tracker.tree, gain)
    new, info = update(state, uv, conf, tracker.config, tracker.tree, gain,
                       before=tracker.state)
    tracker.state = replace(new, stamp=stamp)
    return output(tracker.state, info, uv, conf, tracker.config, gain)


@pytest.mark.parametrize('config', [
    SlqeConfig(), SlqeConfig(output='detection'), SlqeConfig(order=2),
    SlqeConfig(limb_rejected_frames=0, min_confidence=0.2, accel_time_s=math.inf),
    CvConfig().to_slqe()], ids=['default', 'detection', 'order2', 'limb0', 'cv'])
def test_compiled_step_is_the_python_functions(config: SlqeConfig) -> None:
    """The kernel behind `SlqeTracker.step` does the Python functions' work: the same sources
    and state counters every frame, the same numbers but for the matrix products' rounding,
    over detections with noise, outliers (every hypothesis taken), dropouts, unknown
    confidences, scale changes, repeated and skipped stamps, gaps and stamps going back."""
    rng = np.random.default_rng(3)
    hypotheses = set()
    for _ in range(6):
        compiled, python = SlqeTracker(config, PARTS_10), SlqeTracker(config, PARTS_10)
        base, vel = rng.uniform(50, 250, (10, 2)), rng.normal(0, 60, (10, 2))
        stamp = 0.0
        for _ in range(120):
            stamp += rng.choice([1 / FPS, 1 / FPS, 2 / FPS, 0.0, 0.7 if rng.random() < 0.03
                                 else 1 / FPS]) - (1.0 if rng.random() < 0.01 else 0.0)
            if rng.random() < 0.05:
                vel = rng.normal(0, 200, (10, 2))
            base = base + vel / FPS
            uv = base + rng.normal(0, 3, (10, 2))
            outliers = rng.random(10) < 0.15
            uv[outliers] += rng.uniform(-80, 80, (outliers.sum(), 2))
            uv[rng.random(10) < 0.1] = np.nan
            conf = None if rng.random() < 0.1 else rng.uniform(0, 1, 10)
            scale = None if rng.random() < 0.3 else rng.uniform(20, 120)
            want = _python_step(python, uv, conf, stamp, scale)
            got = compiled.step(uv, conf, stamp, scale)
            for name in ('positions', 'covariances', 'velocities', 'source', 'confidence'):
                a, b = getattr(got, name), getattr(want, name)
                assert a.dtype == b.dtype, name
                assert_allclose(a, b, rtol=1e-9, atol=1e-9, err_msg=name)
            assert np.array_equal(got.source, want.source)
            for name in ('active', 'missed', 'rejected', 'shadow_left'):
                assert np.array_equal(getattr(compiled.state, name),
                                      getattr(python.state, name)), name
            for name in ('x', 'cov', 'last_rejected', 'confidence', 'shadow_x', 'shadow_cov'):
                assert_allclose(getattr(compiled.state, name), getattr(python.state, name),
                                rtol=1e-9, atol=1e-6, err_msg=name)
            assert (compiled.state.stamp, compiled.state.dt) == (python.state.stamp,
                                                                 python.state.dt)
            hypotheses.add(int(compiled.state.shadow_left.max()))
    assert len(hypotheses) > 1 or config.shadow_frames == 0  # restarts happened


def test_compiled_step_refuses_a_singular_innovation() -> None:
    """Two parts whose x positions the covariance holds for one (a state no update makes):
    their joint innovation covariance is singular, and the step says so."""
    tracker = SlqeTracker(SlqeConfig(), CHAIN)
    uv = np.array([[10.0, 10.0], [20.0, 10.0], [30.0, 10.0]])
    tracker.step(uv, None, 0.0)
    cov, b = tracker.state.cov.copy(), tracker.config.block
    r = tracker.config.measurement_noise_px ** 2
    cov[0, 0] = cov[b, b] = 1.0
    cov[0, b] = cov[b, 0] = 1.0 + r
    tracker.state = replace(tracker.state, cov=cov)
    with pytest.raises(np.linalg.LinAlgError):
        tracker.step(uv, None, 0.0)  # the same stamp: no prediction, innovations 0
