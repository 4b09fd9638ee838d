"""Boosted trees (core/boost.py, fitted by training/boost.py) and the learned corrections of the
parts (core/refine.py, fitted by training/refiner.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers import INTR
from numpy.testing import assert_allclose

from pose4d_ros.core.boost import BoostedTrees, predict_stacked
from pose4d_ros.core.dpm import load_model, save_model
from pose4d_ros.core.refine import (
    MAX_DEPTH_M,
    MAX_SHIFT_SCALES,
    N_FEATURES,
    QUANTILES,
    PartRefiner,
    features,
    group_of,
    person_scale,
)
from pose4d_ros.core.skeleton import PARTS_14
from pose4d_ros.core.stages import DetectorStage
from pose4d_ros.core.warm_up import warm_up_frame
from pose4d_ros.models import model_path
from pose4d_ros.training.boost import fit
from pose4d_ros.training.refiner import fit_refiner, targets

# --------------------------------------------------------------------------- boosted trees


def test_boosted_trees_learn_a_step_and_ignore_outliers() -> None:
    """The absolute error follows the typical sample: a step in feature 1 (feature 0 is noise)
    with 10 % of the targets wildly off is learned to within a few millimetres, where squared
    error would be pulled by the outliers."""
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (4000, 2))
    y = np.where(x[:, 1] > 0.6, 0.25, -0.05) + rng.normal(0, 0.005, 4000)
    bad = rng.random(4000) < 0.1
    y[bad] += rng.choice([-3.0, 3.0], int(bad.sum()))
    trees = fit(x, y, trees=100, depth=3, learning_rate=0.1)
    probe = np.array([[0.5, 0.2], [0.5, 0.9], [0.1, 0.55], [0.9, 0.65]])
    assert_allclose(trees.predict(probe), [-0.05, 0.25, -0.05, 0.25], atol=0.01)
    # the first tree's root cuts at the step
    assert trees.feature[0, 0] == 1 and trees.threshold[0, 0] == pytest.approx(0.6, abs=0.04)


def test_missing_features_go_left_and_are_learned() -> None:
    """NaN is its own bin: a target that depends on a feature being missing is learned."""
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 1, (2000, 1))
    missing = rng.random(2000) < 0.3
    x[missing] = np.nan
    y = np.where(missing, 0.3, 0.0)
    trees = fit(x, y, trees=60, depth=2, learning_rate=0.2)
    assert_allclose(trees.predict(np.array([[np.nan], [0.2], [0.9]])), [0.3, 0.0, 0.0],
                    atol=0.01)


def test_the_predictor_walks_the_trees_as_written() -> None:
    """One hand-made tree of depth 2: node 0 splits on feature 0 at 1.0, node 1 (left) on
    feature 1 at 5.0, node 2 (right) sends everything left."""
    trees = BoostedTrees(0.5, np.array([[0, 1, 0]], np.int16),
                         np.array([[1.0, 5.0, np.inf]], np.float32),
                         np.array([[10.0, 20.0, 30.0, 40.0]], np.float32))
    x = np.array([[0.0, 0.0], [0.0, 5.0], [1.0, 99.0], [np.nan, 7.0]])
    assert_allclose(trees.predict(x), [10.5, 20.5, 30.5, 20.5])
    both = predict_stacked(np.asarray(x, np.float32), np.array([0, -1, 0, 0]), np.array([0.5]),
                           trees.feature[None], trees.threshold[None], trees.leaf[None])
    assert_allclose(both, [10.5, 0.0, 30.5, 20.5])


def test_bad_trees_and_samples_are_refused() -> None:
    with pytest.raises(ValueError, match='bad tree arrays'):
        BoostedTrees(0.0, np.zeros((1, 3), np.int16), np.zeros((1, 3), np.float32),
                     np.zeros((1, 3), np.float32))
    with pytest.raises(ValueError, match='finite'):
        BoostedTrees(np.nan, np.zeros((1, 1), np.int16), np.zeros((1, 1), np.float32),
                     np.zeros((1, 2), np.float32))
    with pytest.raises(ValueError, match='targets must be finite'):
        fit(np.zeros((100, 1)), np.full(100, np.nan))
    with pytest.raises(ValueError, match='need at least'):
        fit(np.zeros((10, 1)), np.zeros(10))
    with pytest.raises(ValueError, match='do not fit'):
        predict_stacked(np.zeros((2, 1), np.float32), np.zeros(2, np.int64), np.zeros(1),
                        np.ones((1, 1, 1), np.int16), np.zeros((1, 1, 1), np.float32),
                        np.zeros((1, 1, 2), np.float32))


# --------------------------------------------------------------------------- the refiner

def _scene(behind: float):
    """A flat body at 2.5 m (a 40 x 60 px slab) and the parts of PARTS_14 on it, its right
    wrist's joint `behind` metres behind the slab (a hand hidden behind the body)."""
    depth = np.full((INTR.height, INTR.width), np.nan, np.float32)
    depth[90:210, 140:180] = 2.5
    mask = np.isfinite(depth)
    names = PARTS_14.names
    rng = np.random.default_rng(len(names))
    uv = np.column_stack([rng.uniform(145, 175, len(names)), rng.uniform(95, 205, len(names))])
    z = np.full(len(names), 2.5)            # what the look-up reads: the slab
    truth = np.full(len(names), 2.55)       # joint centres 5 cm behind it
    truth[names.index('right_wrist')] += behind
    return names, uv, z, truth, depth, mask


def test_features_read_the_windows_and_the_pose() -> None:
    names, uv, z, _, depth, mask = _scene(0.0)
    x = features(names, PARTS_14.parents, uv, z, np.full(len(names), 0.7), depth, INTR, mask)
    assert x.shape == (len(names), N_FEATURES)
    nq = len(QUANTILES)
    # every window of the flat slab reads the lifted 2.5 m
    assert_allclose(x[:, :3 * nq], 0.0, atol=1e-6)
    assert_allclose(x[:, 3 * nq], 2.5)               # the lifted depth
    assert_allclose(x[:, 3 * nq + 1:3 * nq + 4], 0.0, atol=1e-9)  # parent, root, median
    assert_allclose(x[:, 3 * nq + 7], 0.7, atol=1e-6)
    # a right part's horizontal offset from its parent is mirrored
    i, j = names.index('left_elbow'), names.index('right_elbow')
    mirrored = uv.copy()
    mirrored[j] = mirrored[PARTS_14.parents[j]] + (mirrored[i] - mirrored[PARTS_14.parents[i]]
                                                   ) * [-1, 1]
    xm = features(names, PARTS_14.parents, mirrored, z, np.ones(len(names)), depth, INTR, mask)
    assert xm[j, 3 * nq + 4] == pytest.approx(xm[i, 3 * nq + 4], abs=1e-5)
    # a part without a depth has no features; outside the person the windows read nothing
    z2 = z.copy()
    z2[3] = np.nan
    x2 = features(names, PARTS_14.parents, uv, z2, np.ones(len(names)), depth, INTR,
                  np.zeros_like(mask))
    assert np.isnan(x2[3]).all() and np.isnan(x2[:, :3 * nq]).all()
    with pytest.raises(ValueError, match='differ in shape'):
        features(names, PARTS_14.parents, uv, z, z, depth, INTR, mask[1:])


def test_the_probes_read_the_body_along_the_limb_and_across_it() -> None:
    """A forearm pointing right (left wrist) and its mirror image (right wrist) on the slab,
    whose upper half is 5 cm nearer: back along the forearm and on it the probes read the body,
    further on (beyond the slab) nothing; across it, the mirrored part's sides are mirrored."""
    names, _, z, _, depth, mask = _scene(0.0)
    depth[90:146] = 2.45
    uv = np.full((len(names), 2), 160.0)
    le, lw = names.index('left_elbow'), names.index('left_wrist')
    re, rw = names.index('right_elbow'), names.index('right_wrist')
    uv[le], uv[lw] = (150.0, 150.0), (170.0, 150.0)
    uv[re], uv[rw] = (170.0, 150.0), (150.0, 150.0)
    x = features(names, PARTS_14.parents, uv, z, np.ones(len(names)), depth, INTR, mask)
    step = 0.06 * INTR.fx / 2.5
    assert 170 + step + 1 < 180 < 170 + 2 * step - 1  # the third probe is off the slab
    probes = 3 * len(QUANTILES) + 8
    for i in (lw, rw):
        back, on, further, side_a, side_b = x[i, probes:probes + 5]
        assert back == pytest.approx(0.0, abs=1e-6) and on == pytest.approx(0.0, abs=1e-6)
        assert np.isnan(further)
        assert side_a == pytest.approx(0.0, abs=1e-6)        # below the forearm: 2.5 m
        assert side_b == pytest.approx(-0.05, abs=1e-6)      # above it: 2.45 m
    assert np.isnan(x[names.index(PARTS_14.names[PARTS_14.parents.index(-1)]),
                     probes:]).all()  # the root has no limb


def test_a_refiner_learns_where_a_hidden_joint_lies_and_survives_the_model_file(tmp_path
                                                                                ) -> None:
    """Frames where the right wrist is either on the slab or hidden 25 cm behind it and 5 px
    below where it was detected, which its windows alone cannot tell but its 2-D offset from
    the elbow can: fitted, the refiner puts each wrist within a pixel and 2 cm of the truth,
    leaves the other parts where they are, and the model file keeps it."""
    rng = np.random.default_rng(2)
    names = PARTS_14.names
    w, e = names.index('right_wrist'), names.index('right_elbow')
    xs, part, ys, cases = [], [], [], []
    for k in range(600):
        hidden = k % 2 == 1
        _, uv, z, truth, depth, mask = _scene(0.25 if hidden else 0.0)
        uv = uv + rng.normal(0, 1.0, uv.shape)
        uv[w] = uv[e] + ([-12.0, 0.0] if hidden else [12.0, 0.0])
        true_uv = uv.copy()
        true_uv[w, 1] += 5.0 if hidden else 0.0
        conf = np.ones(len(names))
        xs.append(features(names, PARTS_14.parents, uv, z, conf, depth, INTR, mask))
        part.append(np.arange(len(names)))
        ys.append(targets(names, uv, z, true_uv, truth, INTR.fx))
        cases.append((uv, z, true_uv, truth, depth, mask))
    refiner = fit_refiner(names, np.concatenate(xs), np.concatenate(part),
                          np.concatenate(ys), trees=60, depth=3)
    assert set(refiner.groups) == {group_of(n) for n in names}
    model = replace(load_model(model_path('rgbd_14')), refiner=refiner)
    save_model(model, tmp_path / 'm.npz')
    again = load_model(tmp_path / 'm.npz').refiner
    assert again is not None and again.groups == refiner.groups
    for uv, z, true_uv, truth, depth, mask in cases[-4:]:
        conf = np.ones(len(names))
        got_uv, got_z = refiner.apply(names, PARTS_14.parents, uv, z, conf, depth, INTR, mask)
        assert_allclose(got_uv, true_uv, atol=1.0)
        assert_allclose(got_z, truth, atol=0.02)
        uv2, z2 = again.apply(names, PARTS_14.parents, uv, z, conf, depth, INTR, mask)
        assert_allclose(uv2, got_uv, atol=1e-9)
        assert_allclose(z2, got_z, atol=1e-9)
    corr = refiner.corrections(names, np.full((len(names), N_FEATURES), 9.0, np.float32))
    assert (np.abs(corr) <= [MAX_SHIFT_SCALES, MAX_SHIFT_SCALES, MAX_DEPTH_M]).all()


def _constant_refiner(du: float, dv: float, dz: float, groups=('wrist',)) -> PartRefiner:
    """Trees that always say (du, dv, dz): one tree of depth 1 per output, leaves 0."""
    trees = [BoostedTrees(v, np.zeros((1, 1), np.int16), np.full((1, 1), np.inf, np.float32),
                          np.zeros((1, 2), np.float32)) for v in (du, dv, dz)] * len(groups)
    return PartRefiner.stack(groups, trees)


def test_the_detector_stage_moves_its_parts_as_the_refiner_says() -> None:
    """A refiner that moves wrists 0.2 person scales outwards and down and 10 cm back: the
    detector stage's wrists move so (the right one mirrored), on the image, the others not."""
    model = load_model(model_path('rgbd_14'))
    color, depth, mask = warm_up_frame(INTR)
    plain = DetectorStage(replace(model, refiner=None)).step(color, depth, INTR, mask=mask)
    moved = DetectorStage(replace(model, refiner=_constant_refiner(0.2, 0.2, 0.1))).step(
        color, depth, INTR, mask=mask)
    names = plain.names
    scale = person_scale(plain.xyz[:, 2], INTR.fx)
    for n in names:
        i = names.index(n)
        if group_of(n) != 'wrist':
            assert_allclose(moved.uv[i], plain.uv[i])
            assert_allclose(moved.xyz[i], plain.xyz[i])
            continue
        sign = -1.0 if n.startswith('right_') else 1.0
        want = np.clip(plain.uv[i] + scale * np.array([0.2 * sign, 0.2]), 0, [INTR.width - 1,
                                                                           INTR.height - 1])
        assert_allclose(moved.uv[i], want, atol=1e-5)     # float32 trees
        assert moved.xyz[i, 2] == pytest.approx(plain.xyz[i, 2] + 0.1, abs=1e-6)


def test_a_damaged_refiner_in_a_model_file_is_refused(tmp_path) -> None:
    model = load_model(model_path('rgbd_14'))
    good = _constant_refiner(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match='feature indices'):
        replace(good, feature=np.full_like(good.feature, N_FEATURES))
    with pytest.raises(ValueError, match='inconsistent arrays'):
        replace(good, base=good.base[:2])
    path = tmp_path / 'm.npz'
    save_model(replace(model, refiner=good), path)
    data = dict(np.load(path))
    data['refiner_leaf'] = data['refiner_leaf'][:, :, :-1]
    np.savez(path, **data)
    with pytest.raises(ValueError, match=f'{path}: bad part model: part refiner'):
        load_model(path)


def test_the_stages_of_a_cascade_apply_one_after_the_other(tmp_path) -> None:
    """Two stages: the second reads the parts where the first put them and moves them on; the
    model file keeps both, a file from before cascades holds one stage, and a part with a
    lifted depth is moved even where its windows read no body."""
    names, uv, z, _, depth, mask = _scene(0.0)
    parents, conf = PARTS_14.parents, np.ones(len(names))
    first, second = _constant_refiner(0.1, 0.0, 0.05), _constant_refiner(0.0, -0.2, 0.02)
    both = first.then(second)
    assert both.stages == 2
    uv1, z1 = first.apply(names, parents, uv, z, conf, depth, INTR, mask)
    for got, want in zip(both.apply(names, parents, uv, z, conf, depth, INTR, mask, stages=1),
                         (uv1, z1), strict=True):
        assert_allclose(got, want)
    uv2, z2 = second.apply(names, parents, uv1, z1, conf, depth, INTR, mask)
    got_uv, got_z = both.apply(names, parents, uv, z, conf, depth, INTR, mask)
    assert_allclose(got_uv, uv2)
    assert_allclose(got_z, z2)
    w = names.index('left_wrist')
    scale = person_scale(z, INTR.fx)
    assert_allclose(got_uv[w], uv[w] + scale * np.array([0.1, -0.2]), atol=1e-4)
    assert got_z[w] == pytest.approx(z[w] + 0.07, abs=1e-6)
    assert_allclose(np.delete(got_uv, [w, names.index('right_wrist')], axis=0),
                    np.delete(uv, [w, names.index('right_wrist')], axis=0))
    off_body, _ = both.apply(names, parents, uv, z, conf, depth, INTR, np.zeros_like(mask))
    assert_allclose(off_body, got_uv)
    model = replace(load_model(model_path('rgbd_14')), refiner=both)
    save_model(model, tmp_path / 'm.npz')
    again = load_model(tmp_path / 'm.npz').refiner
    assert again is not None and again.stages == 2
    assert_allclose(again.apply(names, parents, uv, z, conf, depth, INTR, mask)[0], got_uv)
    old = first.arrays()
    del old['stages']
    assert PartRefiner.from_arrays(old).stages == 1
    with pytest.raises(ValueError, match='cannot follow'):
        first.then(_constant_refiner(0.0, 0.0, 0.0, groups=('elbow',)))
    with pytest.raises(ValueError, match='stage 2 of a 2-stage'):
        both.corrections(names, np.zeros((len(names), N_FEATURES), np.float32), stage=2)


def test_a_depth_only_stage_learns_the_depth_and_leaves_the_pixels() -> None:
    rng = np.random.default_rng(5)
    names = PARTS_14.names
    x = rng.uniform(0, 1, (3000, N_FEATURES)).astype(np.float32)
    part = rng.integers(0, len(names), 3000)
    target = np.column_stack([np.full(3000, 0.3), np.full(3000, -0.3),
                              np.where(x[:, 2] > 0.5, 0.2, -0.1)])
    refiner = fit_refiner(names, x, part, target, trees=100, depth=2, min_samples=50,
                          outputs=('dz',))
    probe = np.tile(x[:2], (len(names) // 2, 1))
    probe[::2, 2], probe[1::2, 2] = 0.9, 0.1
    c = refiner.corrections(names, probe)
    assert (c[:, :2] == 0).all()
    assert_allclose(c[::2, 2], 0.2, atol=0.02)
    assert_allclose(c[1::2, 2], -0.1, atol=0.02)
    with pytest.raises(ValueError, match='outputs'):
        fit_refiner(names, x, part, target, outputs=('dx',))
