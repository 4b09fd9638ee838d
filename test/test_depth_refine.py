"""Boosted trees (core/boost.py) and the learned depth correction (core/depth_refine.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers import INTR
from numpy.testing import assert_allclose

from pose4d_ros.core.boost import BoostedTrees, fit, predict_stacked
from pose4d_ros.core.depth_refine import (
    MAX_CORRECTION_M,
    N_FEATURES,
    QUANTILES,
    DepthRefiner,
    features,
    fit_refiner,
    group_of,
)
from pose4d_ros.core.dpm import load_model, save_model
from pose4d_ros.core.pipeline import lift_parts
from pose4d_ros.core.skeleton import PARTS_14
from pose4d_ros.models import model_path

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
    assert_allclose(x[:, -1], 0.7, atol=1e-6)
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


def test_a_refiner_learns_where_a_hidden_joint_lies_and_survives_the_model_file(tmp_path
                                                                                ) -> None:
    """Frames where the right wrist is either on the slab or 25 cm behind it, which its
    windows alone cannot tell but its 2-D offset from the elbow can: fitted, the refiner puts
    each wrist within 2 cm of its depth, leaves the other parts where they are, and the model
    file keeps it (lift_parts gives the same depths after a save and a load)."""
    rng = np.random.default_rng(2)
    names = PARTS_14.names
    w, e = names.index('right_wrist'), names.index('right_elbow')
    xs, part, target, cases = [], [], [], []
    for k in range(600):
        hidden = k % 2 == 1
        _, uv, z, truth, depth, mask = _scene(0.25 if hidden else 0.0)
        uv = uv + rng.normal(0, 1.0, uv.shape)
        uv[w] = uv[e] + ([-12.0, 0.0] if hidden else [12.0, 0.0])
        x = features(names, PARTS_14.parents, uv, z, np.ones(len(names)), depth, INTR, mask)
        xs.append(x)
        part.append(np.arange(len(names)))
        target.append(truth - z)
        cases.append((uv, z, truth, depth, mask))
    refiner = fit_refiner(names, np.concatenate(xs), np.concatenate(part),
                          np.concatenate(target), trees=60, depth=3)
    assert set(refiner.groups) == {group_of(n) for n in names}
    model = replace(load_model(model_path('rgbd_14')), depth_refiner=refiner,
                    depth_offset_m=None, depth_lookup=None)
    save_model(model, tmp_path / 'm.npz')
    again = load_model(tmp_path / 'm.npz')
    for uv, z, truth, depth, mask in cases[-4:]:
        conf = np.ones(len(names))
        got = lift_parts(model, depth, uv, INTR, mask, conf)
        assert_allclose(got, lift_parts(again, depth, uv, INTR, mask, conf), atol=1e-9)
        # lift_parts reads the slab (2.5 m, no offset): the refiner adds what the truth has
        assert_allclose(got, truth, atol=0.02)
        # without the confidences (as the calibration lifts parts) no correction is made
        assert_allclose(lift_parts(model, depth, uv, INTR, mask), 2.5, atol=1e-6)
    corr = refiner.correction(names, np.full((len(names), N_FEATURES), 9.0, np.float32))
    assert (np.abs(corr) <= MAX_CORRECTION_M).all()


def test_a_damaged_refiner_in_a_model_file_is_refused(tmp_path) -> None:
    model = load_model(model_path('rgbd_14'))
    trees = fit(np.random.default_rng(0).uniform(size=(200, N_FEATURES)), np.zeros(200),
                trees=2, depth=2)
    good = DepthRefiner.stack(['wrist'], [trees])
    with pytest.raises(ValueError, match='feature indices'):
        replace(good, feature=np.full_like(good.feature, N_FEATURES))
    path = tmp_path / 'm.npz'
    save_model(replace(model, depth_refiner=good), path)
    data = dict(np.load(path))
    data['depth_refiner_leaf'] = data['depth_refiner_leaf'][:, :, :-1]
    np.savez(path, **data)
    with pytest.raises(ValueError, match=f'{path}: bad part model: depth refiner'):
        load_model(path)
