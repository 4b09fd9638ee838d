"""The photograph network as a colour unary of the part model's tree (core.dpm.net_unary):
where each level reads the network's maps, what the weights do to the search, and the checks
of its settings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers import person_frame, planted_image, random_net, tenpart_model
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.core.convnet import STRIDE
from pose4d_ros.core.dpm import Detector, PartModel, SearchConfig
from pose4d_ros.core.dpm.net_unary import NetMaps, NetUnary, UnaryConfig
from pose4d_ros.core.hog import N_FEATURES, feature_pyramid


def gaussian_maps(cells: int, centres: list[tuple[float, float]], sigma: float = 2.0,
                  floor: float = -10.0) -> np.ndarray:
    """(cells, cells, J) `log p - floor` of one smooth bump per joint at (x, y) cells."""
    y, x = np.mgrid[0:cells, 0:cells].astype(np.float64)
    logp = np.stack([-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma ** 2) for cx, cy in centres])
    logp -= np.log(np.exp(logp).sum(axis=(1, 2), keepdims=True))
    return np.maximum(logp - floor, 0).transpose(1, 2, 0).astype(np.float32)


def named_net(names: tuple[str, ...]) -> NetUnary:
    """A network whose joints are `names` (its maps are given, never computed)."""
    net = random_net()
    return NetUnary(replace(net, joint_names=names, mirror=tuple(range(len(names)))))


def test_each_filter_position_reads_the_network_at_its_centre() -> None:
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    (level,) = feature_pyramid(image, None, [0.8], sbin=4, pad=(3, 3), origin=(37, 21))
    cells = 32
    # full-image pixels to network input pixels: a crop at (37, 21) scaled by 0.75
    m = np.array([[0.75, 0.0, -37 * 0.75 + 4.0], [0.0, 0.75, -21 * 0.75 + 9.0]])
    values = gaussian_maps(cells, [(12.3, 17.8), (20.0, 6.5)])
    unary = NetUnary(named_net(('a', 'b')).net, UnaryConfig(weight=2.0, floor=-10.0))
    ny, nx = 40, 50
    out = unary.level_unary(NetMaps(values, m), level, (5, 5), ny, nx)
    assert out.shape == (2, ny, nx) and out.dtype == np.float32
    rows, cols = np.mgrid[0:ny, 0:nx]
    u, v = level.cell_to_pixel(rows.astype(float), cols.astype(float), (5, 5))
    qx = (m[0, 0] * u + m[0, 2] + 0.5) / STRIDE - 0.5
    qy = (m[1, 1] * v + m[1, 2] + 0.5) / STRIDE - 0.5
    inside = (qx >= 0) & (qx <= cells - 1) & (qy >= 0) & (qy <= cells - 1)
    assert inside.sum() > 100 and (~inside).sum() > 10
    x0, y0 = np.floor(qx).astype(int), np.floor(qy).astype(int)
    fx, fy = qx - x0, qy - y0
    for j in range(2):
        g = values[:, :, j].astype(np.float64)
        x1, y1 = np.minimum(x0 + 1, cells - 1), np.minimum(y0 + 1, cells - 1)
        xa, ya = np.clip(x0, 0, cells - 1), np.clip(y0, 0, cells - 1)
        bilinear = ((1 - fx) * (1 - fy) * g[ya, xa] + fx * (1 - fy) * g[ya, x1] +
                    (1 - fx) * fy * g[y1, xa] + fx * fy * g[y1, x1])
        expect = 2.0 * (bilinear - 10.0)
        # OpenCV interpolates at 1/32 of a cell
        assert_allclose(out[j][inside], expect[inside], atol=0.05 * 2.0 * 10.0 / 32 * 4)
        # beyond the crop the network rules nothing out: the floor
        far = ~((qx > -1) & (qx < cells) & (qy > -1) & (qy < cells))
        assert_allclose(out[j][far], -20.0)


def test_weight_zero_and_the_hog_as_trained_search_as_without_the_network() -> None:
    rng = np.random.default_rng(0)
    col, depth, mask = person_frame(rng)
    model = tenpart_model()
    plain = Detector(model, SearchConfig(n_levels=2)).detect(col, depth, mask=mask, top_k=3)
    net = random_net()  # its joints are LSPET's, the ten-part model's names among them
    with_net = Detector(model, SearchConfig(n_levels=2),
                        NetUnary(net, UnaryConfig(weight=0.0))).detect(col, depth, mask=mask,
                                                                        top_k=3)
    assert len(plain) == len(with_net)
    for a, b in zip(plain, with_net, strict=True):
        assert_allclose(a.uv, b.uv)
        assert a.score == pytest.approx(b.score, rel=1e-5)


def test_the_hog_weight_scales_the_colour_filters_only() -> None:
    model = tenpart_model('rgbd')
    unary = NetUnary(random_net(), UnaryConfig(hog_weight=0.25))
    wmat = model.filter_matrix()
    scaled = unary.filter_matrix(wmat, model.n_channels).reshape(wmat.shape[0], -1, 64)
    assert model.n_channels == 2
    w = wmat.reshape(wmat.shape[0], -1, 64)
    assert_allclose(scaled[:, :, :N_FEATURES], 0.25 * w[:, :, :N_FEATURES])
    assert_array_equal(scaled[:, :, N_FEATURES:], w[:, :, N_FEATURES:])
    assert NetUnary(random_net()).filter_matrix(wmat, 2) is wmat


def test_a_strong_network_term_moves_a_part_to_its_peak_and_leaves_unknown_parts() -> None:
    """The planted three-part pose of test_dpm; the network puts part 'b' 20 px to the right
    of where the HOG filters put it."""
    rng = np.random.default_rng(0)
    im = planted_image(rng)
    fs = 4
    (level,) = feature_pyramid(im, None, [1.0], sbin=4, pad=(3, 3))
    planted = np.array([[7, 9], [14, 6], [14, 15]])
    mean = level.feat.reshape(-1, 32).mean(0)
    filters = np.stack([level.feat[r:r + fs, c:c + fs] - mean for r, c in planted])[:, None]
    anchors = np.zeros((3, 1, 2), np.int32)
    for c in (1, 2):
        anchors[c, 0] = planted[c, ::-1] - planted[0, ::-1]
    springs = np.tile(np.array([0, 0.01, 0, 0.01], np.float32), (3, 1, 1))
    springs[0] = 0
    m = PartModel(('a', 'b', 'c'), (-1, 0, 0), 'rgb', 4, filters.astype(np.float32), springs,
                  anchors, np.zeros((3, 1, 1), np.float32), 32.0, 0.5, (20.0, 60.0))
    (base,) = Detector(m, SearchConfig(subcell=False)).poses_from_levels([level])
    target = base.uv[1] + np.array([20.0, 0.0])
    # input pixels = image pixels; the network knows 'b' and a part 'x' the model lacks
    transform = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    cells = 96 // STRIDE
    q = (target + 0.5) / STRIDE - 0.5
    values = gaussian_maps(cells, [tuple(q), (3.0, 3.0)], sigma=0.7)
    unary = named_net(('b', 'x'))
    strong = Detector(m, SearchConfig(subcell=False), replace(
        unary, config=UnaryConfig(weight=50.0)))
    (moved,) = strong.poses_from_levels([level], net_maps=NetMaps(values, transform))
    assert np.abs(moved.uv[1] - target).max() <= STRIDE
    assert_allclose(moved.uv[[0, 2]], base.uv[[0, 2]])
    # the score handed on: the part model's at the moved pose, on the scale of its maxima
    c = UnaryConfig()
    assert moved.score == pytest.approx(c.score_scale * moved.part_scores.sum() + c.score_offset)
    assert moved.part_scores.sum() < base.score  # pulled off the model's maximum
    # hog_weight 0 on a colour model: the network alone places 'b', the others keep the tree's
    only = Detector(m, SearchConfig(subcell=False), replace(
        unary, config=UnaryConfig(weight=1.0, hog_weight=0.0)))
    (alone,) = only.poses_from_levels([level], net_maps=NetMaps(values, transform))
    assert np.abs(alone.uv[1] - target).max() <= STRIDE


@pytest.mark.parametrize('field, value, words', [
    ('weight', -1.0, 'weight must be >= 0'), ('hog_weight', float('nan'), 'hog_weight'),
    ('floor', 0.0, 'floor must be a log-probability < 0'), ('scales', (1.3,), 'include 1'),
    ('score_scale', 0.0, 'score_scale must be > 0')])
def test_bad_settings_are_refused_with_the_rule(field: str, value: object, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        UnaryConfig(**{field: value})


@pytest.mark.parametrize('masked', [True, False])
def test_the_network_reads_the_blanked_crop_or_the_camera_s(monkeypatch, masked: bool) -> None:
    """`UnaryConfig.masked`: the network reads the person's crop blanked outside their mask, as
    the part model does, or, off, the camera's colour image (`photo`) as it is."""
    rng = np.random.default_rng(2)
    col, depth, mask = person_frame(rng)
    model = replace(tenpart_model(), masked_input=True)
    read: list[tuple[np.ndarray, tuple]] = []
    original = NetUnary.maps

    def recording(self, color, box):
        read.append((np.asarray(color).copy(), box))
        return original(self, color, box)

    monkeypatch.setattr(NetUnary, 'maps', recording)
    detector = Detector(model, SearchConfig(n_levels=1),
                        NetUnary(random_net(), UnaryConfig(masked=masked)))
    blanked = np.where(mask[:, :, None], col, 0).astype(np.uint8)
    assert detector.detect(blanked, depth, mask=mask, blanked=True, photo=col)
    (image, (x0, y0, x1, y1)), = read
    crop, inside = image[y0:y1, x0:x1], mask[y0:y1, x0:x1]
    assert (~inside).sum() > 1000  # the crop reaches beyond the person
    assert_array_equal(crop[inside], col[y0:y1, x0:x1][inside])
    # beyond the person: the camera's pixels only when the network is not masked
    assert_array_equal(crop[~inside], 0 if masked else col[y0:y1, x0:x1][~inside])
