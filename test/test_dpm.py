"""The part model: distance transforms, tree inference, model files, the QP, bad input."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import person_frame, planted_image, random_model, tenpart_model
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.dpm import Detector, PartModel, SearchConfig, load_model, save_model
from pose4d_ros.core.dpm.dp import (
    LIMB_CANDIDATES,
    backtrack,
    best_roots,
    im2col,
    limb_candidates,
    model_arrays,
    score_level,
    tree_dp,
)
from pose4d_ros.core.dpm.dt import dt2d
from pose4d_ros.core.dpm.infer import OcclusionFloor, arm_limbs
from pose4d_ros.core.hog import feature_pyramid
from pose4d_ros.core.lifting import lift_parts
from pose4d_ros.core.skeleton import PARTS_10, PARTS_14, PARTS_22
from pose4d_ros.training.dpm.samples import TrainConfig
from pose4d_ros.training.dpm.solver import Examples, dcd, margins, rebuild_w
from pose4d_ros.training.dpm.train import choose_depth_lookup, kmeans

# --------------------------------------------------------------------------- distance transforms

def exhaustive_pass(src, a, b, shift):
    """The 1-D transform along axis 0 over every cell, in `dt._pass`'s float64 arithmetic:
    (values as float32, first best q)."""
    n = src.shape[0]
    d = (np.arange(n)[:, None] + shift) - np.arange(n)[None, :]  # [p, q]
    cost = a * d * d + (-b) * d
    val = src.astype(np.float64)[None, :, :] - cost[:, :, None]  # [p, q, j]
    return val.max(axis=1).astype(np.float32), val.argmax(axis=1).astype(np.int32)


@pytest.mark.parametrize('spread', [0.1, 3.0, 1e6])
def test_dt2d_is_the_exhaustive_maximum_exactly(spread: float) -> None:
    """The candidate windows leave out no cell that could win: the same values and argmaxes
    (ties to the first) as a maximum over every cell, bit for bit, from maps whose range is
    far below the springs' costs to far above them; and on a flat map, where all tie."""
    rng = np.random.default_rng(1)
    maps = [(rng.normal(size=(int(rng.integers(1, 30)), int(rng.integers(1, 30)))) * spread)
            .astype(np.float32) for _ in range(30)]
    maps.append(np.full((6, 5), 2.5, np.float32))
    for s in maps:
        ny, nx = s.shape
        wx, wx2, wy, wy2 = (np.float32(v) for v in (rng.normal(), rng.uniform(0.01, 2),
                                                     rng.normal(), rng.uniform(0.01, 2)))
        ax, ay = (int(v) for v in rng.integers(-4, 5, 2))
        if (s == s.flat[0]).all():  # cost 0.5 d^2 - 0.5 d: d = 0 and d = 1 tie exactly
            wx = wx2 = wy = wy2 = np.float32(0.5)
        out = np.empty((ny, nx), np.float32)
        ix = np.empty((ny, nx), np.int32)
        iy = np.empty((ny, nx), np.int32)
        tmp = np.empty((ny, nx), np.float32)
        dt2d(s, wx, wx2, wy, wy2, ax, ay, out, ix, iy, tmp)
        tmp_t, ix_t = exhaustive_pass(s.T, np.float64(wx2), np.float64(wx), ax)
        np.testing.assert_array_equal(tmp, tmp_t.T)
        np.testing.assert_array_equal(ix, ix_t.T)
        out_e, iy_e = exhaustive_pass(tmp, np.float64(wy2), np.float64(wy), ay)
        np.testing.assert_array_equal(out, out_e)
        np.testing.assert_array_equal(iy, iy_e)


def test_dt2d_equals_brute_force() -> None:
    rng = np.random.default_rng(0)
    ny, nx = 7, 9
    for _ in range(10):
        s = rng.normal(size=(ny, nx)).astype(np.float32)
        wx, wx2, wy, wy2 = rng.normal(), rng.uniform(0.05, 1), rng.normal(), rng.uniform(0.05, 1)
        ax, ay = (int(v) for v in rng.integers(-3, 4, 2))
        out = np.empty((ny, nx), np.float32)
        ix = np.empty((ny, nx), np.int32)
        iy = np.empty((ny, nx), np.int32)
        dt2d(s, wx, wx2, wy, wy2, ax, ay, out, ix, iy, np.empty((ny, nx), np.float32))
        yc, xc = np.mgrid[0:ny, 0:nx]
        for y in range(ny):
            for x in range(nx):
                dx, dy = xc - x - ax, yc - y - ay
                val = s - (wx * dx + wx2 * dx * dx + wy * dy + wy2 * dy * dy)
                assert_allclose(out[y, x], val.max(), rtol=1e-5, atol=1e-4)
                cy = iy[y, x]
                cx = ix[cy, x]
                assert_allclose(val[cy, cx], val.max(), rtol=1e-5, atol=1e-4)


# --------------------------------------------------------------------------- tree inference


def test_tree_dp_equals_brute_force_over_all_poses() -> None:
    """A 4-part tree (root with two children, one grandchild) on a 2x3 map, 2 types."""
    rng = np.random.default_rng(0)
    parents = (-1, 0, 1, 0)
    m = random_model(parents)
    p_n, k = 4, 2
    ny, nx = 2, 3
    resp = rng.normal(size=(p_n, k, ny, nx)).astype(np.float32)
    par = np.asarray(parents, np.int64)
    root, ix, iy, ik, _ = tree_dp(resp, par, m.springs, m.anchors, m.bias)
    cells = list(itertools.product(range(ny), range(nx)))

    def pose_score(types, locs):
        s = resp[0, types[0], *locs[0]] + m.bias[0, 0, types[0]]
        for c in range(1, p_n):
            t, (y, x) = types[c], locs[c]
            pt, (py, px) = types[parents[c]], locs[parents[c]]
            dx, dy = x - px - m.anchors[c, t, 0], y - py - m.anchors[c, t, 1]
            sp = m.springs[c, t]
            s += resp[c, t, y, x] - (sp[0] * dx + sp[1] * dx * dx + sp[2] * dy
                                     + sp[3] * dy * dy) + m.bias[c, pt, t]
        return s

    best = np.full((k, ny, nx), -np.inf)
    for types in itertools.product(range(k), repeat=p_n):
        for locs in itertools.product(cells, repeat=p_n - 1):
            for r in cells:
                v = pose_score(types, (r, *locs))
                best[types[0], r[0], r[1]] = max(best[types[0], r[0], r[1]], v)
    assert_allclose(root, best, rtol=1e-5, atol=1e-4)
    # backtracking reproduces the maximum: the parts' shares add up to the root's score
    roots = np.array([[t, y, x] for t in range(k) for y, x in cells], np.int64)
    parts, local = backtrack(roots, par, resp, ix, iy, ik, m.springs, m.anchors, m.bias)
    assert_allclose(local.sum(1), best[roots[:, 0], roots[:, 1], roots[:, 2]], rtol=1e-5,
                    atol=1e-4)
    for j in range(len(roots)):
        assert_allclose(pose_score(parts[j, :, 0], [tuple(c) for c in parts[j, :, 1:]]),
                        local[j].sum(), rtol=1e-5, atol=1e-4)


def test_im2col_rows_are_the_filter_windows() -> None:
    rng = np.random.default_rng(0)
    feat = rng.random((6, 7, 5)).astype(np.float32)
    cols = im2col(feat, 3, 2)
    assert cols.shape == (4 * 6, 3 * 2 * 5)
    for y, x in ((0, 0), (3, 5), (2, 1)):
        assert_array_equal(cols[y * 6 + x], feat[y:y + 3, x:x + 2].ravel())


def test_inference_recovers_a_planted_pose_exactly() -> None:
    """Filters = the HOG windows at planted cells (matched filters), anchors = the planted
    offsets: the best pose is the planted one, and its pixels come back exactly."""
    rng = np.random.default_rng(0)
    im = planted_image(rng)
    fs = 4
    (level,) = feature_pyramid(im, None, [1.0], sbin=4, pad=(3, 3))
    planted = np.array([[7, 9], [14, 6], [14, 15]])            # (row, col) top-left cells
    parents = (-1, 0, 0)
    mean = level.feat.reshape(-1, 32).mean(0)
    filters = np.stack([level.feat[r:r + fs, c:c + fs] - mean for r, c in planted])[:, None]
    anchors = np.zeros((3, 1, 2), np.int32)
    for c in (1, 2):
        anchors[c, 0] = planted[c, ::-1] - planted[0, ::-1]   # (dx, dy)
    springs = np.tile(np.array([0, 0.5, 0, 0.5], np.float32), (3, 1, 1))
    springs[0] = 0
    m = PartModel(('a', 'b', 'c'), parents, 'rgb', 4, filters.astype(np.float32), springs,
                  anchors, np.zeros((3, 1, 1), np.float32), 32.0, 0.5, (20.0, 60.0))
    (pose,) = Detector(m, SearchConfig(subcell=False)).poses_from_levels([level])
    u, v = level.cell_to_pixel(planted[:, 0], planted[:, 1], (fs, fs))
    assert_allclose(pose.uv, np.stack([u, v], 1))
    # sub-cell refinement moves each part by at most half a cell (2 px here)
    (fine,) = Detector(m).poses_from_levels([level])
    assert np.abs(fine.uv - pose.uv).max() <= 2.0 + 1e-9
    assert fine.score == pytest.approx(pose.score)
    res = score_level(level, m)
    r = best_roots(res, 1)
    assert_array_equal(r[0, 1:], planted[0])
    assert pose.flags == ()


# --------------------------------------------------------------------------- tracking prior

ARM_NAMES = ('neck', 'left_shoulder', 'left_elbow', 'left_wrist')


def _arm_model(seed: int = 3) -> PartModel:
    return replace(random_model((-1, 0, 1, 2), k=2, seed=seed), part_names=ARM_NAMES)


def _share(m: PartModel, resp: np.ndarray, c: int, part: np.ndarray, parent: np.ndarray
           ) -> float:
    """Part c's share of a pose's score at (type, row, col) `part` below `parent`."""
    (t, r, q), (pt, pr, pc) = part, parent
    dx, dy = q - pc - m.anchors[c, t, 0], r - pr - m.anchors[c, t, 1]
    sp = m.springs[c, t]
    return float(resp[c, t, r, q] - (sp[0] * dx + sp[1] * dx * dx + sp[2] * dy + sp[3] * dy * dy)
                 + m.bias[c, pt, t])


def test_limb_candidates_start_with_the_dp_arm_and_none_beats_it() -> None:
    rng = np.random.default_rng(4)
    m = _arm_model()
    par = np.asarray(m.parents, np.int64)
    resp = rng.normal(size=(4, 2, 9, 11)).astype(np.float32)
    _, ix, iy, ik, score = tree_dp(resp, par, m.springs, m.anchors, m.bias)
    roots = np.array([[0, 4, 5], [1, 2, 2]], np.int64)
    parts, local = backtrack(roots, par, resp, ix, iy, ik, m.springs, m.anchors, m.bias)
    for j in range(len(roots)):
        cand, loc = limb_candidates(resp, score, ix, iy, ik, par, m.springs, m.anchors, m.bias,
                                    parts[j], 2, 3, LIMB_CANDIDATES)
        assert_array_equal(cand[0], parts[j, 2:4])
        assert_allclose(loc[0], local[j, 2:4], rtol=1e-5, atol=1e-5)
        assert len(cand) > LIMB_CANDIDATES  # other elbows, each with several wrists
        # every candidate's shares are the model's own, and the DP's arm is the best of them
        for (elbow, wrist), shares in zip(cand, loc, strict=True):
            assert_allclose(shares, [_share(m, resp, 2, elbow, parts[j, 1]),
                                     _share(m, resp, 3, wrist, elbow)], rtol=1e-5, atol=1e-5)
        assert loc.sum(1).max() <= loc[0].sum() + 1e-4
        # elbow cells apart from the DP's are at least 2 cells apart from each other
        elbows = np.unique(cand[:, 0, 1:], axis=0)
        for a, b in itertools.combinations(elbows, 2):
            assert np.abs(a - b).max() >= 2 or (a == parts[j, 2, 1:]).all() or \
                (b == parts[j, 2, 1:]).all()
    # a limb without an end (the 10-part tree's wrist) has one share per candidate
    cand, loc = limb_candidates(resp, score, ix, iy, ik, par, m.springs, m.anchors, m.bias,
                                parts[0], 3, -1, LIMB_CANDIDATES)
    assert (cand[:, 1] == -1).all() and (loc[:, 1] == 0).all()
    assert_array_equal(cand[0, 0], parts[0, 3])


def test_arm_limbs_of_the_shipped_trees() -> None:
    i14 = PARTS_14.names.index
    assert arm_limbs(PARTS_14.names, PARTS_14.parents) == (
        (i14('left_elbow'), i14('left_wrist')), (i14('right_elbow'), i14('right_wrist')))
    i10 = PARTS_10.names.index
    assert arm_limbs(PARTS_10.names, PARTS_10.parents) == (
        (i10('left_wrist'), -1), (i10('right_wrist'), -1))
    i22 = PARTS_22.names.index
    assert arm_limbs(PARTS_22.names, PARTS_22.parents) == (
        (i22('left_forearm'), i22('left_wrist')), (i22('right_forearm'), i22('right_wrist')))
    assert arm_limbs(('neck', 'head'), (-1, 0)) == ()


def test_the_prior_moves_an_arm_to_the_candidate_near_it_and_only_then() -> None:
    rng = np.random.default_rng(5)
    m = _arm_model()
    (level,) = feature_pyramid(rng.integers(0, 255, (64, 72, 3)).astype(np.uint8), None, [1.0],
                               sbin=4, pad=(2, 2))
    det = Detector(m, SearchConfig(subcell=False, arm_prior=50.0))
    (free,) = det.poses_from_levels([level])
    _, par, springs, anchors, bias = model_arrays(m)
    res = score_level(level, m)
    parts, _ = backtrack(best_roots(res, 1), par, res.resp, res.ix, res.iy, res.ik, springs,
                         anchors, bias)
    cand, _ = limb_candidates(res.resp, res.score, res.ix, res.iy, res.ik, par, springs, anchors,
                              bias, parts[0], 2, 3, LIMB_CANDIDATES)
    other = cand[len(cand) // 2]
    assert not (other == cand[0]).all()
    u, v = level.cell_to_pixel(other[:, 1], other[:, 2], m.filter_shape)
    prior = np.full((4, 2), np.nan)
    prior[2:] = np.stack([u, v], 1)
    (led,) = det.poses_from_levels([level], prior=prior)
    assert_allclose(led.uv[2:], prior[2:])           # elbow and wrist moved to the prior
    assert_allclose(led.uv[:2], free.uv[:2])         # the rest of the pose did not
    assert led.score == pytest.approx(led.part_scores.sum(), rel=1e-5)
    assert led.score <= free.score + 1e-4
    # no prior, an unknown one, its own arm or a zero weight: the DP's pose
    same = [det.poses_from_levels([level], prior=np.full((4, 2), np.nan))[0],
            det.poses_from_levels([level], prior=free.uv)[0],
            Detector(m, SearchConfig(subcell=False, arm_prior=0.0)).poses_from_levels(
                [level], prior=prior)[0]]
    for pose in same:
        assert_allclose(pose.uv, free.uv)
        assert pose.score == pytest.approx(free.score)
    with pytest.raises(ValueError, match='prior'):
        det.poses_from_levels([level], prior=np.zeros((3, 2)))
    with pytest.raises(ValueError, match='arm_prior'):
        SearchConfig(arm_prior=-1.0)


def test_the_occlusion_floor_raises_the_hidden_positions_alone_to_the_persons_quantile() -> None:
    rng = np.random.default_rng(6)
    m = _arm_model()
    (level,) = feature_pyramid(rng.integers(0, 255, (64, 72, 3)).astype(np.uint8), None, [1.0],
                               sbin=4, pad=(2, 2))
    mask = np.zeros((64, 72), bool)
    mask[:, 36:] = True                    # the person: the right half
    occluder = np.zeros((64, 72), bool)
    occluder[:, :30] = True                # a nearer person: the left part
    plain = score_level(level, m).resp
    floored = score_level(level, m, floor=OcclusionFloor(mask, occluder, 0.5, m.filter_shape))
    ny, nx = plain.shape[2:]
    u, v = level.cell_to_pixel(np.arange(ny)[:, None], np.arange(nx)[None, :], m.filter_shape)
    u = np.broadcast_to(np.clip(np.rint(u), 0, 71), (ny, nx)).astype(int)
    v = np.broadcast_to(np.clip(np.rint(v), 0, 63), (ny, nx)).astype(int)
    hidden, own = occluder[v, u], mask[v, u]
    assert hidden.any() and own.any()
    floor = np.quantile(plain.max(axis=1)[:, own], 0.5, axis=1)
    want = np.where(hidden, np.maximum(plain, floor[:, None, None, None]), plain)
    assert_allclose(floored.resp, want, rtol=1e-6)
    assert (floored.resp > plain).any()                       # some hidden position raised
    assert_array_equal(floored.resp[:, :, ~hidden], plain[:, :, ~hidden])
    # nobody in front, or the floor off: the detector before
    empty = OcclusionFloor(mask, np.zeros_like(mask), 0.5, m.filter_shape)
    assert_array_equal(score_level(level, m, floor=empty).resp, plain)
    det = Detector(m, SearchConfig(subcell=False, occluded_quantile=0.0))
    col = rng.integers(0, 255, (64, 72, 3)).astype(np.uint8)
    (a,) = det.detect(col, box=(0, 0, 72, 64), mask=mask, occluder=occluder)
    (b,) = det.detect(col, box=(0, 0, 72, 64), mask=mask)
    assert_allclose(a.uv, b.uv)
    with pytest.raises(ValueError, match='occluder'):
        OcclusionFloor(mask, occluder[:, :10], 0.5, m.filter_shape)
    with pytest.raises(ValueError, match='occluded_quantile'):
        SearchConfig(occluded_quantile=1.5)


# --------------------------------------------------------------------------- model files


def test_choose_depth_lookup_takes_the_look_up_that_lands_joints_near_the_truth() -> None:
    rng = np.random.default_rng(2)
    n = 200
    truth_z = rng.uniform(2.0, 3.5, n)
    rays = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), np.ones(n)])
    truth = rays * truth_z[:, None]
    right = rng.random(n) < 0.8
    # look-up 0: the surface 6 cm in front, but a third of the time an arm 25 cm in front;
    # look-up 1: the surface 4 cm in front with 1 cm of noise; look-up 2: no reading
    arm = rng.random(n) < 0.33
    depths = np.column_stack([truth_z - 0.06 - 0.25 * arm,
                              truth_z - 0.04 + rng.normal(0, 0.01, n), np.full(n, np.nan)])
    best, offset = choose_depth_lookup(right, rays, truth, depths)
    assert best == 1 and offset == pytest.approx(0.04, abs=0.005)
    assert choose_depth_lookup(np.zeros(n, bool), rays, truth, depths) == (0, 0.0)


def test_lift_parts_reads_each_part_as_the_model_learned() -> None:
    intr = cad60_intrinsics()
    depth = np.full((240, 320), 3.0, np.float32)
    depth[:, 155:166] = 2.7  # an arm 30 cm in front of the torso, across the image's centre
    m = tenpart_model()
    uv = np.tile([[160.0, 120.0]], (m.n_parts, 1))
    assert_allclose(lift_parts(m, depth, uv, intr), 2.7)  # no look-up, no offset: the surface
    offsets = np.full(m.n_parts, 0.05, np.float32)
    lookup = np.tile(np.float32([0.03, 0.5]), (m.n_parts, 1))
    lookup[2] = (0.1, 0.9)  # one part reads the torso behind the arm
    m = replace(m, depth_offset_m=offsets, depth_lookup=lookup)
    z = lift_parts(m, depth, uv, intr)
    assert z[2] == pytest.approx(3.05) and np.delete(z, 2) == pytest.approx(2.75)
    with pytest.raises(ValueError, match='depth_lookup'):
        replace(m, depth_lookup=lookup[:, :1])

def test_model_save_load_round_trip(tmp_path: Path) -> None:
    m = replace(tenpart_model(), depth_offset_m=np.linspace(0.0, 0.09, 10, dtype=np.float32),
                depth_lookup=np.tile(np.float32([0.055, 0.9]), (10, 1)),
                search_range_px=(35.0, 70.0), scale_prior=2.0)
    path = tmp_path / 'm.npz'
    save_model(m, path)
    back = load_model(path)
    for f in m.__dataclass_fields__:
        a, b = getattr(m, f), getattr(back, f)
        if isinstance(a, np.ndarray):
            assert_array_equal(a, b)
            assert a.dtype == b.dtype
        else:
            assert a == b, f
    assert [p.name for p in tmp_path.iterdir()] == ['m.npz']  # no temporary left


def test_bad_model_files_are_refused_with_the_file_name(tmp_path: Path) -> None:
    with pytest.raises(OSError, match='no such model'):
        load_model(tmp_path / 'missing.npz')
    junk = tmp_path / 'junk.npz'
    junk.write_bytes(b'not a zip file at all')
    with pytest.raises(ValueError, match='junk.npz'):
        load_model(junk)
    other = tmp_path / 'other.npz'
    np.savez(other, a=np.zeros(3))
    with pytest.raises(ValueError, match='other.npz.*missing'):
        load_model(other)
    m = tenpart_model()
    bad = tmp_path / 'bad.npz'
    save_model(m, bad)
    with np.load(bad) as d:
        parts = {k: d[k] for k in d.files}
    parts['springs'] = parts['springs'][:, :2]
    np.savez(bad, **parts)
    with pytest.raises(ValueError, match='bad.npz.*springs'):
        load_model(bad)


def test_model_validation() -> None:
    m = tenpart_model()
    with pytest.raises(ValueError, match='channels'):
        PartModel(m.part_names, m.parents, 'xyz', 4, m.filters, m.springs, m.anchors, m.bias,
                  32.0, 0.5, (30.0, 80.0), 'float')
    springs = m.springs.copy()
    springs[3, 0, 1] = 0.0
    with pytest.raises(ValueError, match='w_dx2'):
        PartModel(m.part_names, m.parents, 'rgbd', 4, m.filters, springs, m.anchors, m.bias,
                  32.0, 0.5, (30.0, 80.0), 'float')
    with pytest.raises(ValueError, match='filters'):
        PartModel(m.part_names, m.parents, 'rgb', 4, m.filters, m.springs, m.anchors, m.bias,
                  32.0, 0.5, (30.0, 80.0))


# --------------------------------------------------------------------------- bad input


def test_detect_finds_a_pose_and_maps_it_into_the_box() -> None:
    rng = np.random.default_rng(0)
    col, depth, mask = person_frame(rng)
    det = Detector(tenpart_model(), SearchConfig(n_levels=2))
    poses = det.detect(col, depth, mask=mask, top_k=3)
    assert 1 <= len(poses) <= 3
    assert [p.score for p in poses] == sorted((p.score for p in poses), reverse=True)
    p = poses[0]
    assert p.uv.shape == (10, 2) and p.names == PARTS_10.names
    assert np.all((p.confidence >= 0) & (p.confidence <= 1))
    assert_allclose(p.part_scores.sum(), p.score, rtol=1e-5)
    # the search box is the mask's box plus a margin of 0.4 person scales
    margin = SearchConfig().margin * 285.171 * 0.5 / 2.5 + 10
    assert (p.uv[:, 0] > 130 - margin).all() and (p.uv[:, 0] < 190 + margin).all()


def test_scale_factor_searches_a_person_that_much_larger() -> None:
    rng = np.random.default_rng(0)
    col, depth, mask = person_frame(rng)
    det = Detector(tenpart_model())
    base = det.plan(col.shape[:2], depth, mask=mask)
    big = det.plan(col.shape[:2], depth, mask=mask, scale=2 ** 0.4)
    assert_allclose(base.scales[0] / big.scales[0], 2 ** 0.4)  # a larger person: a smaller level
    assert big.x0 < base.x0 and big.x1 > base.x1  # and a margin as much larger
    (pose,) = det.detect(col, depth, mask=mask, scale=2 ** 0.4)
    assert_allclose(pose.scale, big.scales[0])


def test_the_search_without_depth_covers_the_models_search_range() -> None:
    m = tenpart_model()  # trained range 30-80 px, no search range: the trained range
    wide = Detector(m).plan((240, 320), None)
    narrow = Detector(replace(m, search_range_px=(40.0, 60.0))).plan((240, 320), None)
    for plan, (lo, hi) in ((wide, (30.0, 80.0)), (narrow, (40.0, 60.0))):
        assert not plan.depth_guided
        assert_allclose(m.canonical_scale_px / np.array(plan.scales)[[0, -1]], (lo, hi))
    assert len(narrow.scales) < len(wide.scales)
    with pytest.raises(ValueError, match='search_range_px'):
        replace(m, search_range_px=(60.0, 40.0))


def test_the_scale_prior_ranks_the_levels_searched_without_depth() -> None:
    col, depth, mask = person_frame(np.random.default_rng(0))
    m = tenpart_model()
    by_depth = Detector(m).detect(col, depth, mask=mask)[0]
    sizes = m.canonical_scale_px / np.array(Detector(m).plan(col.shape[:2], None).scales)
    found = {}
    for prior in (-100.0, 0.0, 100.0):
        det = Detector(replace(m, scale_prior=prior))
        (pose,) = det.detect(col, None)
        assert_allclose(pose.part_scores.sum(), pose.score, rtol=1e-5)  # its own score
        found[prior] = m.canonical_scale_px / pose.scale
        assert_allclose(det.detect(col, depth, mask=mask)[0].uv, by_depth.uv)  # by depth: none
    assert_allclose(found[100.0], sizes.max())   # a strong prior: the largest person
    assert_allclose(found[-100.0], sizes.min())  # a strong negative one: the smallest
    assert sizes.min() <= found[0.0] <= sizes.max()
    with pytest.raises(ValueError, match='scale_prior'):
        replace(m, scale_prior=float('nan'))

def test_bad_inputs_give_flagged_or_empty_results() -> None:
    rng = np.random.default_rng(0)
    col, depth, mask = person_frame(rng)
    det = Detector(tenpart_model())
    assert det.detect(col, depth, mask=np.zeros_like(mask)) == []          # empty mask
    assert det.detect(col[:9, :9], depth[:9, :9]) == []                      # tiny frame
    nan_depth = np.full_like(depth, np.nan)
    poses = det.detect(col, nan_depth, mask=mask)                            # no depth at all
    assert len(poses) == 1 and 'no_depth' in poses[0].flags and poses[0].low_confidence
    poses = det.detect(col, np.zeros_like(depth), mask=mask)                 # all-zero depth
    assert len(poses) == 1 and 'no_depth' in poses[0].flags
    with pytest.raises(ValueError, match='mask shape'):
        det.detect(col, depth, mask=mask[:100])
    with pytest.raises(ValueError, match='top_k'):
        det.detect(col, depth, mask=mask, top_k=0)


def test_masked_model_ignores_what_lies_outside_the_mask() -> None:
    rng = np.random.default_rng(0)
    col, depth, mask = person_frame(rng)
    det = Detector(tenpart_model())           # masked_input=True
    a = det.detect(col, depth, mask=mask)[0]
    col2 = col.copy()
    col2[~mask] = 255 - col2[~mask]
    depth2 = np.where(mask, depth, 1.0).astype(np.float32)
    b = det.detect(col2, depth2, mask=mask)[0]
    assert_allclose(a.uv, b.uv)
    assert a.score == pytest.approx(b.score, rel=1e-6)


# --------------------------------------------------------------------------- training pieces

def test_dual_coordinate_descent_reaches_the_svm_optimum() -> None:
    """Random block examples, including structural ones (ref), and a lower bound: the dual
    solution's w equals w0 + sum a y x + sum b e, and the duality gap closes."""
    rng = np.random.default_rng(0)
    p_n, dim, k = 3, 6, 2
    size = p_n * k * dim + p_n * k * 4 + p_n * k * k
    ex = Examples(80, p_n, dim)
    n_pos = 20
    for i in range(60):
        t = rng.integers(0, k, p_n)
        of = np.array([(c * k + t[c]) * dim for c in range(p_n)])
        od = np.array([-1] + [p_n * k * dim + (c * k + t[c]) * 4 for c in range(1, p_n)])
        ob = np.array([p_n * k * dim + p_n * k * 4 + (c * k) * k + t[c] for c in range(p_n)])
        xd = rng.normal(size=(p_n, 4)).astype(np.float32)
        xd[0] = 0
        blocks = (rng.normal(size=(p_n, dim)).astype(np.float32) + (0.5 if i < n_pos else 0),
                  of, xd, od, np.ones(p_n, np.float32), ob)
        if i < n_pos:
            ex.add(blocks, 1.0, 1.0, -1, ('pos', i))
        elif i < 45:
            ex.add(blocks, -1.0, 1.0, -1, ('neg', i))
        else:   # structural: Phi(pos) - Phi(z), own blocks = -Phi(z)
            neg = (-blocks[0], of, -xd, od, -blocks[4], ob)
            ex.add(neg, 1.0, 0.5, int(rng.integers(0, n_pos)), ('pose', i))
    arr = ex.arrays()
    alpha = ex.alpha[:ex.n]
    w0 = rng.normal(size=size) * 0.1
    w = w0.copy()
    lb_idx = np.array([p_n * k * dim + 5], np.int64)
    lb_val = np.array([0.4])
    beta = np.zeros(1)
    c = 0.5
    cost = np.full(ex.n, c)
    for epoch in range(200):
        dcd(w, *arr, alpha, cost, lb_idx, lb_val, beta, 10, epoch)
    # w consistency
    dense = np.zeros((ex.n, size))
    for i in range(ex.n):
        for j in (i, arr[8][i]) if arr[8][i] >= 0 else (i,):
            for cc in range(p_n):
                dense[i, arr[1][j, cc]:arr[1][j, cc] + dim] += arr[0][j, cc]
                if arr[3][j, cc] >= 0:
                    dense[i, arr[3][j, cc]:arr[3][j, cc] + 4] += arr[2][j, cc]
                dense[i, arr[5][j, cc]] += arr[4][j, cc]
    rebuilt = w0 + (alpha * arr[6]) @ dense
    rebuilt[lb_idx] += beta
    assert_allclose(w, rebuilt, atol=1e-8)
    # the same from the duals alone (latent positives rewrite blocks, then rebuild w)
    assert_allclose(rebuild_w(w0, *arr[:7], arr[8], alpha, lb_idx, beta), rebuilt, atol=1e-8)
    assert w[lb_idx[0]] >= lb_val[0] - 1e-9
    # optimality: the duality gap of 1/2|w - w0|^2 + C sum hinge closes
    marg = margins(w, *arr[:7], arr[8])
    assert_allclose(marg, arr[6] * (dense @ w), atol=1e-8)
    u = w - w0
    primal = 0.5 * u @ u + c * np.maximum(0, arr[7] - marg).sum()
    dual = alpha @ arr[7] + beta @ lb_val - 0.5 * u @ u - w0 @ u
    assert primal - dual < 1e-6 * max(1.0, primal)


def test_kmeans_is_deterministic_and_finds_separated_clusters() -> None:
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(m, 0.1, (30, 2)) for m in ((0, 0), (5, 0), (0, 5))])
    c1, l1 = kmeans(x, 3, np.random.default_rng(4))
    c2, l2 = kmeans(x, 3, np.random.default_rng(4))
    assert_array_equal(l1, l2)
    assert sorted(np.bincount(l1).tolist()) == [30, 30, 30]
    assert_allclose(np.sort(np.round(c1).sum(1)), [0, 5, 5])


def test_labelled_pose_score_is_the_tree_dp_at_fixed_cells() -> None:
    """The score of a given pose (`labelled_score`, the tools' check of the labelled pose): at
    the DP's best pose it equals the best score, anywhere else it is no higher (the DP is the
    max over all poses)."""
    from pose4d_ros.core.dpm.dp import backtrack, best_roots, model_arrays, score_level
    from pose4d_ros.core.hog import feature_pyramid
    from pose4d_ros.training.dpm.diagnose import labelled_score

    m = tenpart_model('rgb')
    rng = np.random.default_rng(3)
    img = rng.integers(0, 255, (90, 70, 3), dtype=np.uint8)
    level = feature_pyramid(img, None, [1.0], sbin=4, pad=(3, 3))[0]
    arrays = model_arrays(m)
    res = score_level(level, m, arrays)
    parts, _ = backtrack(best_roots(res, 1), *arrays[1:2], res.resp, res.ix, res.iy, res.ik,
                         *arrays[2:])
    resp = res.resp.astype(np.float64)
    assert labelled_score(resp, parts[0][:, 1:], m) == pytest.approx(res.root.max(), abs=1e-4)
    ny, nx = resp.shape[2:]
    for _ in range(20):
        cells = np.stack([rng.integers(0, ny, 10), rng.integers(0, nx, 10)], 1)
        assert labelled_score(resp, cells, m) <= res.root.max() + 1e-4


def _diagnose_tool():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / 'tools' / 'lspet_diagnose.py'
    spec = importlib.util.spec_from_file_location('lspet_diagnose', path)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_diagnose_summary_splits_by_placement_and_tilt() -> None:
    """Left and right swapped by name, the middle parts kept (`mirror_index`, which the tool
    and mirrored positives use); tools/lspet_diagnose's summary averages the found pose's
    PCK@0.2 over the photographs it lies on the person in and by torso tilt."""
    from pose4d_ros.core.skeleton import mirror_index

    tool = _diagnose_tool()
    names = PARTS_14.names
    swap = mirror_index(names)
    assert names[swap[names.index('left_wrist')]] == 'right_wrist'
    assert swap[names.index('neck')] == names.index('neck')
    assert [swap[i] for i in swap] == list(range(len(names)))
    row = dict(labelled_score=-1.0, same_scale_score=2.0, found_score=3.0, found_scale_ratio=1.0,
               found_pck=10.0, same_scale_pck=20.0, found_swapped_pck20=0.0)
    rows = [dict(row, found_pck20=60.0, found_centre_off=0.1, torso_tilt_deg=10.0,
                 best_of_10_pck20=80.0),
            dict(row, found_pck20=20.0, found_centre_off=0.6, torso_tilt_deg=170.0,
                 best_of_10_pck20=40.0, found_swapped_pck20=50.0)]
    text = tool.summary(rows)
    assert 'PCK@0.2: found 40.0, the best of the 10 best poses 60.0' in text
    assert 'where that fits better 55.0' in text
    assert '50.0 % (PCK@0.2 60.0; elsewhere 20.0)' in text
    assert '0-30 degrees 60.0 (1), 90-180 degrees 20.0 (1)' in text


def test_partial_labels_need_latent_positives() -> None:
    with pytest.raises(ValueError, match='latent_radius'):
        TrainConfig(partial_labels=True)
    with pytest.raises(ValueError, match='latent_radius'):
        TrainConfig(latent_radius=-1)
    assert TrainConfig(partial_labels=True, latent_radius=1).min_labelled == 10


def _labelled_frame(rng: np.random.Generator, names: tuple[str, ...], key: str = 'f',
                    **kw: object):
    """A noise photograph 160 x 200 with the named joints labelled inside its middle."""
    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.datasets.frame import Frame

    uv = np.stack([rng.uniform(60, 100, len(names)), rng.uniform(60, 140, len(names))], 1)
    truth = JointSet(tuple(names), uv, confidence=np.ones(len(names), np.float32))
    color = rng.integers(0, 255, (200, 160, 3), dtype=np.uint8)
    return Frame(0, color, kw.pop('depth_m', None), None, truth, key=key, **kw)


def test_jittered_positive_moves_the_crop_origin_not_the_labels() -> None:
    from pose4d_ros.training.dpm.samples import prepare_positive

    cfg = TrainConfig(parts='10', channels='rgb', jitter=1)
    rng = np.random.default_rng(5)
    f = _labelled_frame(rng, cfg.tree.names)
    p0 = prepare_positive(f, 0, False, 20.0, cfg.tree, cfg)
    p1 = prepare_positive(f, 0, False, 20.0, cfg.tree, cfg, (2, 1))
    assert p0 is not None and p1 is not None
    assert p1.box == (p0.box[0] + 2, p0.box[1] + 1, p0.box[2], p0.box[3])
    assert_allclose(p1.offsets, p0.offsets)
    # the same parts on another phase of the cell grid: other windows, cells at most one apart
    assert np.abs(p1.cells - p0.cells).max() <= 1
    assert not np.allclose(p1.patches, p0.patches)
    with pytest.raises(ValueError, match='shift'):
        prepare_positive(f, 0, False, 20.0, cfg.tree, cfg, (-1, 0))
    with pytest.raises(ValueError, match='jitter'):
        TrainConfig(jitter=9)
    with pytest.raises(ValueError, match='search_percent'):
        TrainConfig(search_percent=50.0)


def test_bone_scale_sees_through_a_torso_seen_end_on() -> None:
    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.datasets.frame import Frame
    from pose4d_ros.training.dpm.samples import bone_ratios, bone_scale, joint_scale, person_scale

    tree = PARTS_14
    rng = np.random.default_rng(8)
    # upright people of torso 40-60 px, bones in fixed proportions with a little noise
    frac = {'head': 0.5, 'shoulder': 0.3, 'elbow': 0.55, 'wrist': 0.5, 'hip': 1.0, 'knee': 0.75,
            'ankle': 0.75}
    frames = []
    for _ in range(40):
        torso = rng.uniform(40, 60)
        uv = np.zeros((len(tree), 2))
        for p, c in tree.edges():
            if tree.names[c].endswith('hip'):   # both torso sides exactly `torso` long
                uv[c] = uv[p] + (0.0, torso)
                continue
            d = frac[tree.names[c].removeprefix('left_').removeprefix('right_')]
            a = rng.uniform(0, 2 * np.pi)
            uv[c] = uv[p] + torso * d * rng.uniform(0.97, 1.03) * np.array([np.cos(a), np.sin(a)])
        frames.append((uv, np.ones(len(tree), bool)))
    ratios = bone_ratios(frames, tree)
    want = [frac[tree.names[c].removeprefix('left_').removeprefix('right_')]
            for _, c in tree.edges()]
    assert_allclose(ratios, want, rtol=0.03)
    # the same person bent towards the camera: the torso a quarter as long, the limbs not
    uv, lab = frames[0]
    torso = np.hypot(*(uv[tree.index('left_hip')] - uv[tree.index('left_shoulder')]))
    bent = uv.copy()
    for side in ('left_', 'right_'):
        h, s = tree.index(side + 'hip'), tree.index(side + 'shoulder')
        shift = (uv[h] - uv[s]) * 0.75
        for name in ('hip', 'knee', 'ankle'):
            bent[tree.index(side + name)] = uv[tree.index(side + name)] - shift
    assert joint_scale(bent, tree.names) == pytest.approx(torso / 4)
    assert bone_scale(bent, lab, tree, ratios) == pytest.approx(torso, rel=0.05)
    # a frame without depth takes it when the config has ratios; too few bones: NaN
    cfg = TrainConfig(parts='14', channels='rgb', bone_ratios=ratios)
    f = Frame(0, np.zeros((300, 300, 3), np.uint8), None, None,
              JointSet(tree.names, bent + 150, confidence=np.ones(len(tree), np.float32)))
    assert person_scale(f, tree.names, cfg) == pytest.approx(torso, rel=0.05)
    few = np.zeros(len(tree), bool)
    few[[tree.index('neck'), tree.index('head'), tree.index('left_shoulder')]] = True
    assert np.isnan(bone_scale(bent, few, tree, ratios))
    with pytest.raises(ValueError, match='bone_ratios'):
        TrainConfig(parts='14', bone_ratios=ratios[:-1])
    with pytest.raises(ValueError, match='left_ankle'):
        bone_ratios([(uv, np.array([n != 'left_ankle' for n in tree.names]))], tree)


def test_background_rooms_come_first_and_lose_depth_for_rgb() -> None:
    from pose4d_ros.training.dpm.negatives import build_negatives

    cfg = TrainConfig(parts='10', channels='rgb')
    rng = np.random.default_rng(6)
    photos = [_labelled_frame(rng, cfg.tree.names, f'p{i}') for i in range(3)]
    rooms = []
    for i, x0 in enumerate((10, 110)):   # the person on the left, then on the right
        mask = np.zeros((200, 160), bool)
        mask[50:150, x0:x0 + 30] = True
        rooms.append(_labelled_frame(rng, cfg.tree.names, f'r{i}', video='v',
                                     depth_m=np.full((200, 160), 2.0, np.float32), mask=mask))
    negs = build_negatives(photos, cfg, 4, 0, rooms)
    assert len(negs) == 4 and negs[0].key == 'v (room)'
    assert negs[0].color.shape == (200, 160, 3) and negs[0].depth_m is None
    assert all('room' not in n.key for n in negs[1:])
    with pytest.raises(ValueError, match='room'):
        build_negatives(photos, cfg, 4, 0, photos)
