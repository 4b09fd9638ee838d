"""The photograph joint network (core.convnet): its ONNX Runtime graph against a numpy
reference of the same layers, transforms, targets, decoding, file format, the PyTorch twin it
is trained as (when PyTorch is installed) and the shipped model on real LSPET photographs (when
../shared/data is here)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import MIRROR, NAMES, random_net
from numpy.lib.stride_tricks import sliding_window_view
from numpy.testing import assert_allclose, assert_array_equal

from pose4d_ros.core import convnet as cn
from pose4d_ros.core.convnet import ConvNet
from pose4d_ros.core.metrics import reference_size
from pose4d_ros.models import model_path


def numpy_conv(x: np.ndarray, w: np.ndarray, b: np.ndarray, stride: int) -> np.ndarray:
    """'Same' convolution of (H, W, C) by (k, k, C, O) weights, odd k, one matrix product (the
    numpy inference the network ran before ONNX Runtime: the reference here)."""
    k = w.shape[0]
    if k > 1:
        p = k // 2
        x = np.pad(x, ((p, p), (p, p), (0, 0)))
        win = sliding_window_view(x, (k, k), axis=(0, 1))[::stride, ::stride]
        h, ww = win.shape[:2]
        cols = win.transpose(0, 1, 3, 4, 2).reshape(h * ww, -1)
    else:
        x = x[::stride, ::stride]
        h, ww = x.shape[:2]
        cols = x.reshape(h * ww, -1)
    return (cols @ w.reshape(-1, w.shape[-1]) + b).reshape(h, ww, -1)


def numpy_forward(net: ConvNet, x: np.ndarray) -> np.ndarray:
    """(J, H/4, W/4) scores of the (H, W, 3) normalised input, in numpy: the layers as
    `training.convnet_torch` trains them (the reference of `ConvNet.forward`)."""
    w = net.weights

    def block(x: np.ndarray, name: str, stride: int) -> np.ndarray:
        y = np.maximum(numpy_conv(x, *w[name + '.c1'], stride), 0)
        y = numpy_conv(y, *w[name + '.c2'], 1)
        skip = w.get(name + '.skip')
        return np.maximum(y + (x if skip is None else numpy_conv(x, *skip, stride)), 0)

    def up2(x: np.ndarray) -> np.ndarray:
        return x.repeat(2, axis=0).repeat(2, axis=1)

    x = np.maximum(numpy_conv(np.ascontiguousarray(x, dtype=np.float32), *w['stem'], 2), 0)
    a = block(block(x, 's2.0', 2), 's2.1', 1)
    b = block(block(a, 's3.0', 2), 's3.1', 1)
    c = block(block(block(b, 's4.0', 2), 's4.1', 1), 's4.2', 1)
    y = block(up2(c) + numpy_conv(b, *w['l3'], 1), 'u3', 1)
    y = block(up2(y) + numpy_conv(a, *w['l2'], 1), 'u2', 1)
    return numpy_conv(y, *w['head'], 1).transpose(2, 0, 1)


def assert_same_scores(ours: np.ndarray, reference: np.ndarray) -> None:
    """float32 sums in another order: within a millionth of the scores' range."""
    assert ours.shape == reference.shape and ours.dtype == np.float32
    assert np.abs(ours - reference).max() <= 2e-6 * np.abs(reference).max() + 1e-6


@pytest.mark.parametrize('stride', [1, 2])
@pytest.mark.parametrize('k', [1, 3])
def test_the_reference_convolution_is_the_direct_sum(stride: int, k: int) -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(9, 8, 3)).astype(np.float32)
    w = rng.normal(size=(k, k, 3, 5)).astype(np.float32)
    b = rng.normal(size=5).astype(np.float32)
    p = k // 2
    xp = np.pad(x, ((p, p), (p, p), (0, 0)))
    rows, cols = range(0, 9, stride), range(0, 8, stride)
    direct = np.array([[np.einsum('ijc,ijco->o', xp[r:r + k, c:c + k], w) + b for c in cols]
                       for r in rows])
    assert_allclose(numpy_conv(x, w, b, stride), direct, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize('shape', [(64, 64), (96, 160)])
def test_onnx_runtime_computes_what_the_numpy_layers_do(shape: tuple[int, int]) -> None:
    net = random_net(width=8, seed=3)
    rng = np.random.default_rng(4)
    xs = cn.normalise(rng.integers(0, 256, (3, *shape, 3)))
    reference = np.stack([numpy_forward(net, x) for x in xs])
    assert reference.shape == (3, 14, shape[0] // 4, shape[1] // 4)
    assert_same_scores(net.forward_batch(xs), reference)  # a batch
    assert_same_scores(net.forward(xs[1]), reference[1])  # one input, another size: same session
    assert_same_scores(net.forward(xs[2][:, ::-1]), numpy_forward(net, xs[2][:, ::-1]))


def test_the_shipped_model_runs_in_onnx_runtime_as_in_numpy() -> None:
    net = cn.load_convnet(model_path('lspet_convnet'))
    rng = np.random.default_rng(5)
    for px in (128, 96):  # its own input and a smaller reading (`UnaryConfig.input_px`)
        x = cn.normalise(rng.integers(0, 256, (px, px, 3)))
        assert_same_scores(net.forward(x), numpy_forward(net, x))


def test_one_session_a_network_made_when_it_first_runs() -> None:
    import copy
    import pickle
    from dataclasses import replace

    net = random_net()
    assert net._session is None and 'session' not in repr(net)
    x = cn.normalise(np.random.default_rng(6).integers(0, 256, (64, 64, 3)))
    scores = net.forward(x)
    session = net._session
    assert session is not None and net.session() is session
    net.forward(x[:32])
    assert net._session is session
    # copies and pickles leave the session behind, and make their own when run
    for other in (pickle.loads(pickle.dumps(net)), copy.deepcopy(net),
                  replace(net, input_px=96)):
        assert other._session is None
        assert_array_equal(other.forward(x), scores)
    with pytest.raises(ValueError, match=r'multiples of 16, got \(1, 60, 64, 3\)'):
        net.forward(x[:60])


def test_crop_transform_centres_scales_turns_and_mirrors() -> None:
    m = cn.crop_transform((200, 100), 128)
    assert_allclose(m @ [50, 100, 1], [64, 64])  # centre to centre
    assert_allclose(m @ [50, 0, 1], [64, 0])  # the longer side fills the input
    turned = cn.crop_transform((200, 100), 128, rotation_deg=90)
    assert_allclose(turned @ [50, 0, 1], [0, 64], atol=1e-9)  # up turns to the left
    mirrored = cn.crop_transform((200, 100), 128, mirror=True)
    assert_allclose(mirrored @ [0, 100, 1], [128 - (m @ [0, 100, 1])[0], 64])
    with pytest.raises(ValueError, match='image 0x100'):
        cn.crop_transform((0, 100), 128)


def test_targets_peak_at_the_joint_and_weigh_only_labelled_joints_on_the_grid() -> None:
    uv = np.array([[30.0, 50.0], [np.nan, np.nan], [500.0, 10.0]])
    t, w = cn.cell_targets(uv, np.array([True, False, True]), 32)
    assert t.shape == (3, 32, 32) and t.dtype == np.float32
    assert_allclose(t.sum(axis=(1, 2)), 1.0, rtol=1e-5)
    y, x = np.unravel_index(t[0].argmax(), (32, 32))
    assert (x, y) == (7, 12)  # (30 + 0.5) / 4 - 0.5 = 7.1, (50 + 0.5) / 4 - 0.5 = 12.1
    assert_allclose(w, [1, 0, 0])  # unlabelled; off the grid


def test_decode_returns_the_peak_in_photograph_pixels() -> None:
    m = cn.crop_transform((300, 150), 128)  # photograph pixels x 128 / 300
    logp = np.full((2, 32, 32), -50.0)
    logp[0, 10, 20] = 0.0
    # the parabola through -1.0, -0.1, -0.4 tops a quarter cell to the right
    logp[1, 5, 5:8] = -1.0, -0.1, -0.4
    logp[1, 4:7, 6] = -0.6, -0.1, -0.6  # and evenly between its upper and lower neighbours
    uv, prob = cn.decode(logp, m)
    inverse = np.linalg.inv(np.vstack([m, [0, 0, 1]]))[:2]
    assert_allclose(uv[0], inverse @ [20 * 4 + 1.5, 10 * 4 + 1.5, 1])
    assert_allclose(uv[1], inverse @ [6.25 * 4 + 1.5, 5 * 4 + 1.5, 1])
    assert_allclose(prob, [1.0, np.exp(-0.1)])
    # a neighbour as high as the peak: half way, never beyond
    logp[0, 10, 21] = 0.0
    assert_allclose(cn.decode(logp, m)[0][0], inverse @ [20.5 * 4 + 1.5, 10 * 4 + 1.5, 1])


def test_detect_sees_the_mirror_image_with_left_and_right_swapped() -> None:
    net = random_net()
    rng = np.random.default_rng(1)
    photo = rng.integers(0, 256, (64, 50, 3), dtype=np.uint8)  # input pixel = photo pixel
    logp, _ = net.heat_maps(photo, (1.0,))
    logp_mirrored, _ = net.heat_maps(np.ascontiguousarray(photo[:, ::-1]), (1.0,))
    # the photograph is centred in the square input: the mirrored photograph's map of a joint
    # is the map of its counterpart, mirrored
    assert_allclose(logp_mirrored, logp[list(MIRROR), :, ::-1], atol=1e-4)
    assert_allclose(np.exp(logp).sum(axis=(1, 2)), 1.0, rtol=1e-4)
    uv, prob = net.detect(photo)
    assert uv.shape == (14, 2) and prob.shape == (14,) and np.isfinite(uv).all()
    with pytest.raises(ValueError, match=r'uint8, got \(64, 50\)'):
        net.detect(photo[..., 0])


def test_file_round_trip_and_errors_name_the_file(tmp_path: Path) -> None:
    net = random_net()
    path = tmp_path / 'net.npz'
    cn.save_convnet(net, path)
    assert cn.is_convnet(path) and not cn.is_convnet(model_path('rgb_10'))
    back = cn.load_convnet(path)
    assert back.joint_names == NAMES and back.mirror == MIRROR and back.metadata == {'seed': 0}
    x = cn.normalise(np.random.default_rng(2).integers(0, 256, (64, 64, 3)))
    # float16 weights: within a small fraction of the scores' spread
    scores = net.forward(x)
    assert np.abs(back.forward(x) - scores).max() < 0.01 * scores.std()
    with pytest.raises(ValueError, match='rgb_10.npz: not a network model'):
        cn.load_convnet(model_path('rgb_10'))
    broken = tmp_path / 'broken.npz'
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k != 'head.w'}
    np.savez(broken, **arrays)
    with pytest.raises(ValueError, match=r"broken.npz: no weights for layer 'head'"):
        cn.load_convnet(broken)
    with pytest.raises(ValueError, match='no permutation'):
        ConvNet(NAMES, (0,) * 14, 64, net.weights)
    header = json.loads(str(np.load(path)['header']))
    assert header['format'] == cn.FORMAT


def test_the_pytorch_twin_computes_what_onnx_runtime_does() -> None:
    """In this Python if it has PyTorch, else in the training venv (`make test` builds it)."""
    import importlib.util
    import os
    import subprocess
    import sys

    script = Path(__file__).with_name('twin_check.py')
    if importlib.util.find_spec('torch') is not None:
        sys.path.insert(0, str(script.parent))
        from twin_check import TOLERANCE, twin_difference
        assert twin_difference() <= TOLERANCE
        return
    train_python = Path(__file__).parents[1] / '.venv-train' / 'bin' / 'python'
    if not train_python.exists():
        pytest.skip('no PyTorch here and no training venv (make train-env)')
    repo = script.parents[1]  # this checkout's code, not the venv's installed copy
    run = subprocess.run([str(train_python), str(script)], capture_output=True, text=True,
                         timeout=300, cwd=repo, env={**os.environ, 'PYTHONPATH': str(repo)})
    assert run.returncode == 0, run.stdout + run.stderr
    assert 'largest difference' in run.stdout


def test_the_shipped_model_finds_people_in_held_out_photographs(shared_data: Path) -> None:
    from pose4d_ros.datasets import lspet

    root = shared_data / 'lspet'
    net = cn.load_convnet(model_path('lspet_convnet'))
    # trained on LSPET 1-2500 and 3001-8500 and four render sets within an hour (both cores)
    assert net.metadata['data'] == 'LSPET 1-2500,3001-8500'
    assert len(net.metadata['renders']) == 4 and net.metadata['train_minutes'] <= 60
    frames = list(lspet.read_frames(root, 2501, 2540))
    truth = np.array([f.truth.uv for f in frames])
    visible = np.array([f.truth.confidence > 0 for f in frames])
    pred = np.array([net.detect(f.color)[0] for f in frames])
    size = reference_size(truth, visible)
    hit = (np.linalg.norm(pred - truth, axis=2) <= 0.2 * size[:, None]) & visible
    # 40 held-out photographs: the HOG mixture of parts places about a third within 0.2
    assert hit.sum() / visible.sum() > 0.5


def test_the_shipped_twin_places_the_joints_the_float_graph_places_on_this_cpu(
        shared_data: Path) -> None:
    """The 8-bit twin's weights span 7 bits (`core.convnet.quantize`): at 8, ONNX Runtime's
    AVX2 kernel (VPMADDUBSW) saturates pairs of products, and on a CPU without VNNI the twin
    placed 17 % of these joints more than 0.05 of the person's size from the float graph's
    (LSPET validation 50.9 / 69.7 PCK@0.1 / @0.2 against the float graph's 54.3 / 73.1)."""
    from pose4d_ros.datasets import lspet

    net = cn.load_convnet(model_path('lspet_convnet'))
    assert net.metadata['quantized']['format'].startswith('ONNX QDQ: weights int8 per channel '
                                                          'at 7 bits')
    frames = list(lspet.read_frames(shared_data / 'lspet', 2501, 2540))
    truth = np.array([f.truth.uv for f in frames])
    visible = np.array([f.truth.confidence > 0 for f in frames])
    float_uv = np.array([net.detect(f.color)[0] for f in frames])
    twin = replace(net, precision='int8')
    twin_uv = np.array([twin.detect(f.color)[0] for f in frames])
    apart = np.linalg.norm(twin_uv - float_uv, axis=2) / reference_size(truth, visible)[:, None]
    assert (apart[visible] <= 0.05).mean() > 0.95  # 0.98 with 7 bits on an AVX2-only CPU


def test_the_shipped_model_places_the_joints_it_placed_in_numpy(shared_data: Path,
                                                               monkeypatch) -> None:
    from pose4d_ros.datasets import lspet

    net = cn.load_convnet(model_path('lspet_convnet'))
    frames = list(lspet.read_frames(shared_data / 'lspet', 2501, 2503))
    found = [net.detect(f.color) for f in frames]
    monkeypatch.setattr(ConvNet, 'forward_batch',
                        lambda self, xs: np.stack([numpy_forward(self, x) for x in xs]))
    for f, (uv, prob) in zip(frames, found, strict=True):
        uv_numpy, prob_numpy = net.detect(f.color)
        assert_allclose(uv, uv_numpy, atol=0.01)  # photograph pixels
        assert_allclose(prob, prob_numpy, rtol=1e-4)


@pytest.mark.parametrize('k', [0.8, 1.25])
def test_a_map_read_at_another_scale_lands_on_the_same_photograph_pixel(k: float) -> None:
    shape = (300, 200)
    m1, mk = cn.crop_transform(shape, 128), cn.crop_transform(shape, 128, scale=k)
    photo_px = np.array([120.0, 160.0, 1.0])
    cell_k = ((mk @ photo_px) + 0.5) / 4 - 0.5
    cell_1 = ((m1 @ photo_px) + 0.5) / 4 - 0.5
    assert_allclose(cn._cell_map(m1, mk) @ np.r_[cell_1, 1.0], cell_k, atol=1e-9)


def test_more_scales_keep_the_maps_distributions() -> None:
    net = random_net()
    photo = np.random.default_rng(3).integers(0, 256, (80, 60, 3), dtype=np.uint8)
    one, m = net.heat_maps(photo, (1.0,))
    assert_allclose(net.heat_maps(photo)[0], net.heat_maps(photo, cn.PHOTO_SCALES)[0])
    logp, m2 = net.heat_maps(photo, (0.85, 1.0, 1.2))
    assert_allclose(m2, m) and logp.shape == one.shape
    assert_allclose(np.exp(logp).sum(axis=(1, 2)), 1.0, rtol=1e-4)
    assert np.abs(logp - one).max() > 1e-3  # the other scales count
    with pytest.raises(ValueError, match=r'include 1.*got \(1.2,\)'):
        net.detect(photo, (1.2,))


def test_a_cpu_budget_counts_this_process_s_cpu_time_not_the_wall_clock() -> None:
    import time

    from pose4d_ros.training.convnet_torch import Budget

    c0 = time.process_time()
    cpu = Budget(cpu_minutes=0.01, cpu_since=c0)
    wall = Budget(minutes=10.0)
    time.sleep(0.2)
    # the CPU budget moves by this process's CPU time only (asleep: what other threads spent,
    # e.g. BLAS threads of earlier tests spinning down), never by the 0.2 s of wall time
    spent = time.process_time() - c0
    assert cpu.done() == pytest.approx(spent / 0.6, abs=0.01) and 0 < wall.done() < 0.01
    end = time.process_time() + 0.3
    while time.process_time() < end:
        pass
    assert cpu.done() >= 0.45 and cpu.text == '0.01 CPU min' and wall.text == '10.0 min'
    # counted from the process's start by default: this one is already spent
    assert Budget(cpu_minutes=time.process_time() / 120.0).done() == 1.0
    with pytest.raises(ValueError, match='either'):
        Budget(minutes=1.0, cpu_minutes=1.0)
    with pytest.raises(ValueError, match='> 0'):
        Budget(cpu_minutes=0.0)


def tiny_lspet(root: Path, n: int, seed: int = 0) -> Path:
    """An LSPET root of `n` random 80x60 photographs, every joint labelled inside them."""
    import cv2
    import scipy.io

    (root / 'images').mkdir(parents=True)
    rng = np.random.default_rng(seed)
    joints = np.ones((14, 3, n))
    joints[:, 0] = rng.uniform(10, 50, (14, n))
    joints[:, 1] = rng.uniform(10, 70, (14, n))
    scipy.io.savemat(root / 'joints.mat', {'joints': joints})
    for i in range(1, n + 1):
        cv2.imwrite(str(root / 'images' / f'im{i:05d}.jpg'),
                    rng.integers(0, 256, (80, 60, 3), dtype=np.uint8))
    return root


def test_train_convnet_trains_on_several_ranges_within_a_cpu_budget(tmp_path: Path) -> None:
    pytest.importorskip('torch', reason='PyTorch trains the network only (make train-env); '
                        'the suite runs without it')
    import time

    from pose4d_ros.cli.main import main

    root = tiny_lspet(tmp_path / 'lspet', 72)
    out = tmp_path / 'net.npz'
    # the process's CPU time counts from its start: what pytest spent so far plus 8 s
    budget = f'{(time.process_time() + 8.0) / 60.0:.5f}'
    started = time.process_time()
    assert main(['train-convnet', str(root), '--range', '1-32,41-72', '--input-px', '64',
                 '--width', '4', '--threads', '1', '--cpu-minutes', budget,
                 '--out', str(out)]) == 0
    # the budget is checked between steps: a step (the first compiles oneDNN's kernels) over
    assert time.process_time() - started < 8.0 + 5.0
    meta = cn.load_convnet(out).metadata
    assert meta['data'] == 'LSPET 1-32,41-72' and meta['photographs'] == 64
    assert meta['steps'] >= 2 and meta['epochs'] >= 1
    assert meta['budget'] == f'{float(budget)} CPU min'
    assert meta['cpu_minutes'] >= float(budget) - 0.06 and meta['train_minutes'] >= 0
    assert meta['threads'] == 1


def test_render_crops_cut_the_person_as_the_detector_sees_them() -> None:
    from pose4d_ros.core.joints import JointSet
    from pose4d_ros.core.skeleton import CAD60_JOINTS
    from pose4d_ros.datasets.frame import Frame
    from pose4d_ros.training.convnet_torch import render_crops

    rng = np.random.default_rng(4)
    color = rng.integers(1, 256, (240, 320, 3), dtype=np.uint8)
    mask = np.zeros((240, 320), bool)
    mask[40:200, 100:160] = True  # 160 rows: a margin of 0.12 is 19.2 px
    n = len(CAD60_JOINTS)
    uv = np.c_[rng.uniform(100, 160, n), rng.uniform(40, 200, n)]
    hand = CAD60_JOINTS.index('left_hand')
    uv[hand] = (5.0, 5.0)  # outside the crop: not labelled
    truth = JointSet(CAD60_JOINTS, uv)
    frames = [Frame(0, color, None, None, truth, mask), Frame(1, color, None, None, truth, None),
              Frame(2, color, None, None, truth, mask, people=(truth, truth))]
    images, pix, labelled = render_crops(frames, NAMES)
    assert len(images) == 1 and pix.shape == (1, 14, 2) and labelled.shape == (1, 14)
    crop = images[0]
    # the box widened by 19.2 px, outwards to whole pixels: rows 20-219, columns 80-179
    assert crop.shape == (200, 100, 3)
    assert not crop[:20].any() and not crop[:, :20].any()  # blanked outside the mask
    assert_array_equal(crop[20:180, 20:80], color[40:200, 100:160])
    for j, name in enumerate(NAMES):
        i = CAD60_JOINTS.index({'left_wrist': 'left_hand', 'right_wrist': 'right_hand',
                                'left_ankle': 'left_foot', 'right_ankle': 'right_foot'
                                }.get(name, name))
        if i == hand:
            assert not labelled[0, j] and np.isnan(pix[0, j]).all()
        else:
            assert labelled[0, j]
            assert_allclose(pix[0, j], uv[i] - (80, 20))


def _photographs_and_renders(tmp_path: Path, takes: str) -> tuple[Path, Path]:
    """Eight tiny LSPET photographs and a rendered set of four frames a take."""
    from helpers import write_utkinect

    from pose4d_ros.cli.main import main

    root = tiny_lspet(tmp_path / 'lspet', 8, seed=1)
    write_utkinect(tmp_path / 'ut')
    renders = tmp_path / 'renders'
    assert main(['synth', '--utkinect', str(tmp_path / 'ut'), '--out', str(renders), '--seed',
                 '3', '--takes', takes, '--frames', '4', '--stride', '3',
                 '--videos-per-take', '1', '--quiet']) == 0
    return root, renders


def test_train_convnet_adds_rendered_people_and_trains_in_bfloat16(tmp_path: Path) -> None:
    pytest.importorskip('torch', reason='PyTorch trains the network only (make train-env); '
                        'the suite runs without it')
    from pose4d_ros.cli.main import main

    root, renders = _photographs_and_renders(tmp_path, 's01-s02')
    out = tmp_path / 'net.npz'
    assert main(['train-convnet', str(root), '--range', '1-8', '--renders', str(renders),
                 '--render-stride', '2', '--input-px', '64', '--width', '4', '--threads', '1',
                 '--minutes', '0.05', '--precision', 'bf16', '--out', str(out)]) == 0
    meta = cn.load_convnet(out).metadata
    assert meta['renders'] == {str(renders): 4} and meta['photographs'] == 8  # 2 x 4 / 2
    assert meta['precision'] == 'bf16' and meta['steps'] >= 1 and meta['cpu']


def test_a_network_fine_tuned_starts_as_the_network_it_was(tmp_path: Path) -> None:
    torch = pytest.importorskip('torch', reason='PyTorch trains the network only (make '
                                'train-env); the suite runs without it')
    from pose4d_ros.cli.main import main
    from pose4d_ros.training.convnet_torch import export_weights, import_weights, network

    before = random_net(width=4, seed=5)
    net = network(torch, 4, len(before.joint_names))
    import_weights(torch, net, before.weights)
    for name, (w, b) in export_weights(net).items():  # the folded weights come back
        assert_allclose(w, before.weights[name][0], atol=1e-6)
        assert_allclose(b, before.weights[name][1], atol=1e-6)
    x = np.random.default_rng(6).uniform(-0.5, 0.5, (1, 64, 64, 3)).astype(np.float32)
    with torch.no_grad():
        ours = net.eval()(torch.from_numpy(x).permute(0, 3, 1, 2)).numpy()
    assert np.abs(ours - before.forward_batch(x)).max() <= 1e-4 * np.abs(ours).max()
    with pytest.raises(ValueError, match='another --width'):
        import_weights(torch, network(torch, 8, 14), before.weights)
    # fine-tuned from a file, on renders that keep their background
    root, renders = _photographs_and_renders(tmp_path, 's01')
    first = tmp_path / 'first.npz'
    cn.save_convnet(replace(before, metadata={'data': 'random'}), first)
    out = tmp_path / 'tuned.npz'
    assert main(['train-convnet', str(root), '--range', '1-8', '--renders', str(renders),
                 '--render-background', '--init', str(first), '--lr', '1e-4', '--input-px',
                 '64', '--width', '4', '--threads', '1', '--minutes', '0.05', '--out',
                 str(out)]) == 0
    meta = cn.load_convnet(out).metadata
    assert meta['init'] == str(first) and meta['init_metadata'] == {'data': 'random'}
    assert meta['render_background'] and meta['lr'] == 1e-4 and meta['steps'] >= 1
    assert meta['renders'] == {str(renders): 8}  # 4 frames, blanked and as rendered
    assert main(['train-convnet', str(root), '--init', str(first), '--out', str(out)]) == 2


def test_the_8_bit_twin_reads_photographs_as_the_float_graph_does(tmp_path: Path) -> None:
    from pose4d_ros.cli.main import main

    root = tiny_lspet(tmp_path / 'lspet', 24)
    src, out = tmp_path / 'net.npz', tmp_path / 'net_int8.npz'
    cn.save_convnet(random_net(input_px=64), src)
    assert main(['quantize-convnet', str(src), str(root), '--range', '1-24',
                 '--photographs', '12', '--out', str(out)]) == 0
    net = cn.load_convnet(out)
    assert net.quantized and net.precision == 'fp32'
    assert net.metadata['quantized']['photographs'] == 12
    assert net.metadata['quantized']['data'] == 'LSPET 1-24'
    assert_array_equal(net.weights['stem'][0], cn.load_convnet(src).weights['stem'][0])
    int8 = replace(net, precision='int8')
    photo = np.random.default_rng(5).integers(0, 256, (80, 60, 3), dtype=np.uint8)
    logp, m = net.heat_maps(photo)
    logp8, m8 = int8.heat_maps(photo)
    assert_array_equal(m, m8)
    # the same distributions over the cells, not the same numbers: 8-bit activations
    p, p8 = np.exp(logp), np.exp(logp8)
    assert np.abs(p - p8).sum(axis=(1, 2)).max() < 0.5  # total variation x 2
    assert not np.array_equal(logp, logp8)  # the twin, not the float graph, ran
    # a network without a twin cannot run at int8, and says how to make one
    with pytest.raises(ValueError, match='quantize-convnet'):
        replace(cn.load_convnet(src), precision='int8')
    with pytest.raises(ValueError, match='precision'):
        replace(net, precision='int4')


def test_the_shipped_network_s_8_bit_twin_places_what_the_float_graph_places(
        shared_data: Path) -> None:
    from pose4d_ros.datasets import lspet

    net = cn.load_convnet(model_path('lspet_convnet'))
    int8 = replace(net, precision='int8')
    frames = list(lspet.read_frames(shared_data / 'lspet', 2501, 2520))
    size = reference_size(np.array([f.truth.uv for f in frames]),
                          np.array([f.truth.confidence > 0 for f in frames]))
    moved = np.array([np.linalg.norm(net.detect(f.color)[0] - int8.detect(f.color)[0], axis=1)
                      / s for f, s in zip(frames, size, strict=True)])
    # most joints within a hundredth of the person's size; a few move to another peak
    assert np.median(moved) < 0.01 and (moved < 0.05).mean() > 0.9
