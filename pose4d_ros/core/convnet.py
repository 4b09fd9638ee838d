"""A small convolutional joint model for RGB photographs: each joint's heat map.

The HOG mixture of parts (`core.dpm`) places about a third of LSPET's joints within PCK@0.2 on
real photographs, and about 40 % on the photographs it was trained on: HOG templates cannot
hold real appearance (the models' README). This model learns the appearance instead: a
fully convolutional network (a residual encoder to 1/16 of the input, decoded with skip
connections to 1/4) gives, for each joint, a score for every cell of a 4-pixel grid over the
photograph, trained with a softmax over the cells against a Gaussian around the labelled joint
(as the keypoint heads of Mask R-CNN, He et al. 2017). A joint is put at its map's best cell
(refined to the top of the parabola through it and its neighbours); its confidence is the softmax
probability there. The mirrored photograph is searched too and the two maps averaged.

The input is the whole photograph, padded to a square and resized to `input_px` (LSPET's
photographs are cut around their person: `crop_transform`); training (`pose4d
train-convnet`, which needs PyTorch) turns, scales, shifts and mirrors it with the same
transform. Inference runs in ONNX Runtime on the CPU (`onnx_model` builds the graph from the
weights when a network is first run, batch normalisation folded into them; one thread, the
graph optimised), so the nodes and `pose4d eval` need no PyTorch.

`quantize` adds an 8-bit twin of the graph (ONNX Runtime's static QDQ quantisation: weights
per output channel, activations at ranges calibrated on inputs as the network reads them),
kept in the same file and run when `precision` is 'int8': the same network at a third of the
CPU on CPUs with 8-bit dot products (VNNI), at 0.6 of it on one without (AVX2). Its weights
span 7 bits, not 8 (`reduce_range`): ONNX Runtime multiplies uint8 activations by int8 weights
with AVX2's VPMADDUBSW, which saturates a pair of products at 16 bits; with the full 8 bits
the twin's heat maps differ by CPU (on an AVX2-only AMD EPYC their peaks left the float
graph's in 43 % of LSPET 8501-8580's maps, against 22 % at 7 bits; docs/NOTES.md).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.files import NPZ_ERRORS, read_npz, write_npz

FORMAT = 'pose4d-convnet-1'
PRECISIONS = ('fp32', 'int8')
STRIDE = 4  # input pixels per heat-map cell
PAD_VALUE = 114  # grey outside the photograph
# The photograph's scales read by `ConvNet.detect` by default (`heat_maps`)
PHOTO_SCALES: tuple[float, ...] = (1.0, 1.3)
CALIBRATION_PHOTOGRAPHS = 256  # about as many calibrate the 8-bit twin (`quantize`)


def layer_names() -> list[str]:
    """The convolutions of the network, in the order of `ConvNet.forward` (each `name.w`
    (k, k, C_in, C_out) and `name.b` (C_out,) in the file)."""
    names = ['stem']
    for stage, blocks in (('s2', 2), ('s3', 2), ('s4', 3)):
        for i in range(blocks):
            names += [f'{stage}.{i}.c1', f'{stage}.{i}.c2']
            if i == 0:
                names.append(f'{stage}.{i}.skip')
    names += ['l3', 'u3.c1', 'u3.c2', 'u3.skip', 'l2', 'u2.c1', 'u2.c2', 'u2.skip', 'head']
    return names


def crop_transform(shape: Sequence[int], input_px: int, *, scale: float = 1.0,
                   rotation_deg: float = 0.0, mirror: bool = False,
                   shift_px: tuple[float, float] = (0.0, 0.0)) -> NDArray[np.float64]:
    """(2, 3) affine from photograph pixels to network input pixels: the photograph's centre
    (plus `shift_px`) to the input's, its longer side to `input_px` times `scale`, turned by
    `rotation_deg` (counter-clockwise on the image), mirrored left-right when `mirror`."""
    h, w = int(shape[0]), int(shape[1])
    if h < 1 or w < 1 or input_px < STRIDE:
        raise ValueError(f'crop_transform: image {h}x{w}, input {input_px} px')
    cx, cy = w / 2.0 + shift_px[0], h / 2.0 + shift_px[1]
    m = cv2.getRotationMatrix2D((cx, cy), rotation_deg, input_px / max(h, w) * scale)
    m[:, 2] += np.array([input_px / 2.0 - cx, input_px / 2.0 - cy])
    if mirror:
        m = np.array([[-1.0, 0.0, input_px], [0.0, 1.0, 0.0]]) @ np.vstack([m, [0, 0, 1]])
    return m


def warp(color: NDArray[np.uint8], transform: NDArray[np.float64], input_px: int
         ) -> NDArray[np.uint8]:
    """The network's (input_px, input_px, 3) input: `color` through `transform`, grey outside."""
    return cv2.warpAffine(color, transform, (input_px, input_px), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=(PAD_VALUE,) * 3)


def normalise(images: NDArray) -> NDArray[np.float32]:
    """uint8 (or float 0-255) RGB to the network's input values, -0.5 to 0.5."""
    return (np.asarray(images, dtype=np.float32) / 255.0 - 0.5).astype(np.float32)


def cell_targets(uv: NDArray[np.floating], visible: NDArray[np.bool_], cells: int,
                 sigma_cells: float = 1.0) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Training targets: per joint a Gaussian over the (cells, cells) grid around the joint's
    input pixel `uv`, summing to 1, and a weight (1 where the joint is labelled and on the
    grid, else 0)."""
    g = np.arange(cells, dtype=np.float64)
    q = (np.asarray(uv, dtype=np.float64) + 0.5) / STRIDE - 0.5  # cell coordinates
    with np.errstate(invalid='ignore'):
        inside = np.isfinite(q).all(axis=1) & (q > -1).all(axis=1) & (q < cells).all(axis=1)
    q = np.where(inside[:, None], q, 0.0)
    d2 = (g[None, None, :] - q[:, 0, None, None]) ** 2 + \
        (g[None, :, None] - q[:, 1, None, None]) ** 2
    t = np.exp(-d2 / (2 * sigma_cells ** 2))
    t /= t.sum(axis=(1, 2), keepdims=True)
    return t.astype(np.float32), (np.asarray(visible, dtype=bool) & inside).astype(np.float32)


ONNX_OPSET = 17
_SESSION_LOCK = threading.Lock()  # one session per network, however many threads ask


def onnx_model(weights: dict[str, tuple[NDArray[np.float32], NDArray[np.float32]]]) -> Any:
    """The network as an ONNX model (an `onnx.ModelProto`) of `weights` (`ConvNet.weights`):
    input `x` (N, 3, H, W) float32 normalised (`normalise`), H and W multiples of 16, output
    `scores` (N, J, H/4, W/4). 'Same' convolutions (odd k, k // 2 zeros each side, 3x3 and 1x1
    of stride 2 keeping rows 0, 2, 4, ...), ReLU, residual blocks, nearest-neighbour upsampling
    by 2 and the 1x1 skips, as `ConvNet` is trained (`training.convnet_torch`)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes: list[Any] = []
    inits: list[Any] = []

    def conv(x: str, name: str, stride: int) -> str:
        w, b = weights[name]
        k = int(w.shape[0])
        inits.append(numpy_helper.from_array(
            np.ascontiguousarray(np.asarray(w, np.float32).transpose(3, 2, 0, 1)), name + '.w'))
        inits.append(numpy_helper.from_array(np.asarray(b, np.float32), name + '.b'))
        nodes.append(helper.make_node('Conv', [x, name + '.w', name + '.b'], [name],
                                      kernel_shape=[k, k], strides=[stride, stride],
                                      pads=[k // 2] * 4, name=name))
        return name

    def op(kind: str, inputs: list[str], out: str, **attrs: Any) -> str:
        nodes.append(helper.make_node(kind, inputs, [out], name=out, **attrs))
        return out

    def block(x: str, name: str, stride: int) -> str:
        y = op('Relu', [conv(x, name + '.c1', stride)], name + '.c1.relu')
        y = conv(y, name + '.c2', 1)
        skip = x if name + '.skip' not in weights else conv(x, name + '.skip', stride)
        return op('Relu', [op('Add', [y, skip], name + '.add')], name + '.out')

    def up2(x: str) -> str:
        return op('Resize', [x, '', 'up2.scales'], x + '.up2', mode='nearest',
                  coordinate_transformation_mode='asymmetric', nearest_mode='floor')

    inits.append(numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), 'up2.scales'))
    x = op('Relu', [conv('x', 'stem', 2)], 'stem.relu')
    a = block(block(x, 's2.0', 2), 's2.1', 1)
    b = block(block(a, 's3.0', 2), 's3.1', 1)
    c = block(block(block(b, 's4.0', 2), 's4.1', 1), 's4.2', 1)
    y = block(op('Add', [up2(c), conv(b, 'l3', 1)], 'u3.in'), 'u3', 1)
    y = block(op('Add', [up2(y), conv(a, 'l2', 1)], 'u2.in'), 'u2', 1)
    nodes.append(helper.make_node('Identity', [conv(y, 'head', 1)], ['scores'], name='scores'))
    joints = int(weights['head'][0].shape[-1])
    graph = helper.make_graph(
        nodes, 'pose4d_convnet',
        [helper.make_tensor_value_info('x', TensorProto.FLOAT, ['N', 3, 'H', 'W'])],
        [helper.make_tensor_value_info('scores', TensorProto.FLOAT,
                                       ['N', joints, 'H4', 'W4'])], inits)
    model = helper.make_model(graph, producer_name='pose4d_ros.core.convnet',
                              opset_imports=[helper.make_opsetid('', ONNX_OPSET)])
    model.ir_version = 8  # the IR of opset 17: any runtime that reads the opset reads it
    onnx.checker.check_model(model)
    return model


def inference_session(model: bytes) -> Any:
    """An ONNX Runtime CPU session of the serialised `model` (`onnx_model`): one thread (nodes
    run one after the other on the calling thread), every graph optimisation on (convolutions
    fused with their ReLU and residual sums, blocked memory layouts)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3  # errors only
    return ort.InferenceSession(model, sess_options=opts,
                                providers=['CPUExecutionProvider'])


@dataclass(frozen=True)
class ConvNet:
    """A trained joint heat-map network (`save_convnet`/`load_convnet`).

    `weights[name]` = ((k, k, C_in, C_out) float32, (C_out,) float32) for each of
    `layer_names()`, batch normalisation folded in. `joint_names` in the heat maps' order;
    `mirror` the index of each joint's left/right counterpart. `metadata`: the training
    command, data, time and seed.
    """

    joint_names: tuple[str, ...]
    mirror: tuple[int, ...]
    input_px: int
    weights: dict[str, tuple[NDArray[np.float32], NDArray[np.float32]]]
    metadata: dict[str, Any] = field(default_factory=dict)
    channels: str = 'rgb'
    # the 8-bit twin of the graph (a serialised ONNX model, `quantize`; empty: none) and the
    # graph run: 'fp32' (`onnx_model` of the weights) or 'int8' (the twin)
    quantized: bytes = field(default=b'', repr=False)
    precision: str = 'fp32'
    # the ONNX Runtime session, made when the network first runs (`session`)
    _session: Any = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        missing = [n for n in layer_names() if n not in self.weights]
        if missing:
            raise ValueError(f'ConvNet: no weights for layers {missing}')
        if sorted(self.mirror) != list(range(len(self.joint_names))):
            raise ValueError(f'ConvNet: mirror {self.mirror} is no permutation of the joints')
        if self.input_px % 32:
            raise ValueError(f'ConvNet: input_px must be a multiple of 32, got {self.input_px}')
        if self.precision not in PRECISIONS:
            raise ValueError(f'ConvNet: precision must be one of {PRECISIONS}, got '
                             f'{self.precision!r}')
        if self.precision == 'int8' and not self.quantized:
            raise ValueError("ConvNet: precision 'int8' needs the network's 8-bit twin "
                             '(pose4d quantize-convnet)')

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != '_session'}  # not picklable

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state, _session=None)

    def session(self) -> Any:
        """The network's ONNX Runtime session (`inference_session` of `onnx_model`, or of the
        8-bit twin when `precision` is 'int8'), made on the first call."""
        if self._session is None:
            with _SESSION_LOCK:
                if self._session is None:
                    graph = self.quantized if self.precision == 'int8' else \
                        onnx_model(self.weights).SerializeToString()
                    object.__setattr__(self, '_session', inference_session(graph))
        return self._session

    def forward_batch(self, x: NDArray[np.floating]) -> NDArray[np.float32]:
        """(N, J, S/4, S/4) scores of N (S, S, 3) normalised inputs (`normalise`), in one run."""
        x = np.asarray(x, dtype=np.float32)
        if x.ndim != 4 or x.shape[3] != 3 or x.shape[1] % 16 or x.shape[2] % 16:
            raise ValueError(f'ConvNet: input must be (N, H, W, 3), H and W multiples of 16, '
                             f'got {x.shape}')
        nchw = np.ascontiguousarray(x.transpose(0, 3, 1, 2))
        return self.session().run(None, {'x': nchw})[0]

    def forward(self, x: NDArray[np.floating]) -> NDArray[np.float32]:
        """(J, S/4, S/4) scores of the (S, S, 3) normalised input (`normalise`)."""
        return self.forward_batch(np.asarray(x)[None])[0]

    def heat_maps(self, color: NDArray[np.uint8], scales: Sequence[float] = PHOTO_SCALES, *,
                  mirror: bool = True) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """Log-probabilities (J, S/4, S/4) of each joint over the cells of `color` ((H, W, 3)
        uint8 RGB), the photograph and its mirror image averaged (the photograph alone unless
        `mirror`: half the work), and the (2, 3) transform from photograph to input pixels.
        `scales`: the photograph is also read enlarged (or shrunk) by each factor (1 among
        them), and each map, brought back onto the grid of scale 1, averaged in where it sees
        the photograph."""
        color = np.asarray(color)
        if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
            raise ValueError(f'ConvNet: colour must be (H, W, 3) uint8, got {color.shape} '
                             f'{color.dtype}')
        if not valid_scales(scales):
            raise ValueError(f'ConvNet: scales must include 1 and lie within 0.25..4, got '
                             f'{tuple(scales)}')
        m = crop_transform(color.shape, self.input_px)
        cells = self.input_px // STRIDE
        transforms = [crop_transform(color.shape, self.input_px, scale=k) for k in scales]
        inputs = [normalise(warp(color, mk, self.input_px)) for mk in transforms]
        if mirror:
            inputs += [x[:, ::-1] for x in inputs]
        scores = self.forward_batch(np.stack(inputs))  # every reading in one run
        total, weight = 0.0, 0.0
        for i, (k, mk) in enumerate(zip(scales, transforms, strict=True)):
            s = scores[i]
            if mirror:
                s = 0.5 * (s + scores[len(scales) + i][list(self.mirror), :, ::-1])
            w = np.ones((cells, cells), np.float32)
            if k != 1.0:
                a = _cell_map(m, mk)
                s = np.stack([cv2.warpAffine(c, a, (cells, cells), flags=cv2.INTER_LINEAR
                                             | cv2.WARP_INVERSE_MAP,
                                             borderMode=cv2.BORDER_REPLICATE) for c in s])
                w = cv2.warpAffine(w, a, (cells, cells), flags=cv2.INTER_LINEAR
                                   | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT)
            total = total + s * w
            weight = weight + w
        s = total / np.maximum(weight, 1e-6)
        s = s - s.max(axis=(1, 2), keepdims=True)
        return s - np.log(np.exp(s).sum(axis=(1, 2), keepdims=True)), m

    def detect(self, color: NDArray[np.uint8], scales: Sequence[float] = PHOTO_SCALES
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(J, 2) photograph pixels of each joint and (J,) its probability at that cell."""
        logp, m = self.heat_maps(color, scales)
        return decode(logp, m)


def valid_scales(scales: Sequence[float]) -> bool:
    """Whether `scales` can be `ConvNet.heat_maps`' reading scales: 1 among them (its grid is
    the one the others are brought onto), each within 0.25..4."""
    return 1.0 in scales and all(0.25 <= k <= 4.0 for k in scales)


def _cell_map(m1: NDArray[np.float64], mk: NDArray[np.float64]) -> NDArray[np.float64]:
    """(2, 3) affine from the cells of input transform `m1` to those of `mk` (the same
    photograph through two transforms)."""
    c = np.array([[STRIDE, 0.0, STRIDE / 2 - 0.5], [0.0, STRIDE, STRIDE / 2 - 0.5], [0, 0, 1]])
    full = np.linalg.inv(c) @ np.vstack([mk, [0, 0, 1]]) @ np.linalg.inv(
        np.vstack([m1, [0, 0, 1]])) @ c
    return full[:2]


def decode(logp: NDArray[np.floating], transform: NDArray[np.float64]
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each map's best cell, moved along each axis to the top of the parabola through it and
    its two neighbours' log-probabilities (at most half a cell), in the pixels the (2, 3)
    `transform` maps to the input; and the probability at the best cell. (Chosen on LSPET
    8501-9000, two networks: PCK@0.1 +0.5 and +0.8 against a quarter cell towards the larger
    neighbour, PCK@0.2 the same within 0.3.)"""
    n, cells = logp.shape[0], logp.shape[1]
    flat = logp.reshape(n, -1).argmax(axis=1)
    y, x = np.divmod(flat, cells)
    j = np.arange(n)
    peak = logp[j, y, x]
    cx = x + _vertex(logp[j, y, np.maximum(x - 1, 0)], peak,
                     logp[j, y, np.minimum(x + 1, cells - 1)])
    cy = y + _vertex(logp[j, np.maximum(y - 1, 0), x], peak,
                     logp[j, np.minimum(y + 1, cells - 1), x])
    uv_in = np.stack([(cx + 0.5) * STRIDE - 0.5, (cy + 0.5) * STRIDE - 0.5], axis=1)
    inverse = cv2.invertAffineTransform(transform)
    uv = np.c_[uv_in, np.ones(n)] @ inverse.T
    return uv, np.exp(logp[j, y, x]).astype(np.float64)


def _vertex(before: NDArray, peak: NDArray, after: NDArray) -> NDArray[np.float64]:
    """Offset of the top of the parabola through (-1, before), (0, peak), (1, after) from 0,
    within half a cell (0 where the three do not bend down)."""
    bend = 2.0 * peak - before - after
    with np.errstate(divide='ignore', invalid='ignore'):
        offset = np.where(bend > 1e-9, 0.5 * (after - before) / bend, 0.0)
    return np.clip(offset, -0.5, 0.5).astype(np.float64)


QUANTIZED = 'int8.onnx'  # the file's array holding the 8-bit twin's bytes


def quantize(net: ConvNet, inputs: Iterable[NDArray[np.floating]]) -> ConvNet:
    """`net` with its 8-bit twin (`ConvNet.quantized`): ONNX Runtime's static quantisation of
    `onnx_model` in QDQ form, weights int8 per output channel at 7 bits (module docstring:
    no x86 CPU's kernel saturates them), activations uint8 over the
    ranges (min to max) the float graph reaches on `inputs`, each an (N, S, S, 3) batch of
    normalised inputs (`normalise`) as the network will read them."""
    import tempfile

    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.batches = (
                {'x': np.ascontiguousarray(np.asarray(x, np.float32).transpose(0, 3, 1, 2))}
                for x in inputs)

        def get_next(self) -> dict[str, NDArray[np.float32]] | None:
            return next(self.batches, None)

    with tempfile.TemporaryDirectory(prefix='pose4d-quantize-') as tmp:
        out = Path(tmp) / 'int8.onnx'
        quantize_static(onnx_model(net.weights), out, Reader(), quant_format=QuantFormat.QDQ,
                        per_channel=True, reduce_range=True, activation_type=QuantType.QUInt8,
                        weight_type=QuantType.QInt8)
        return replace(net, quantized=out.read_bytes())


def calibration_photographs(numbers: Sequence[int], n: int = CALIBRATION_PHOTOGRAPHS
                             ) -> list[int]:
    """About `n` of the training photographs `numbers`, evenly spread (every k-th): those
    `quantize` calibrates on, after training (`pose4d train-convnet`) and alone (`pose4d
    quantize-convnet`)."""
    return list(numbers[::max(len(numbers) // n, 1)])


def calibration_batches(images: Sequence[NDArray[np.uint8]], input_px: int, batch: int = 16
                        ) -> Iterator[NDArray[np.float32]]:
    """The network's inputs of `images` (photographs or crops, RGB uint8) as the detector reads
    them (`ConvNet.heat_maps` at scale 1) and their mirror images, in batches."""
    for i in range(0, len(images), batch):
        x = np.stack([normalise(warp(c, crop_transform(c.shape, input_px), input_px))
                      for c in images[i:i + batch]])
        yield np.concatenate([x, x[:, :, ::-1]])


def save_convnet(net: ConvNet, path: str | Path) -> None:
    """Write the network as .npz (to a temporary name, renamed when complete); weights kept
    as float16 (the model's outputs change by less than the cell's quarter)."""
    header = {'format': FORMAT, 'joint_names': list(net.joint_names),
              'mirror': list(net.mirror), 'input_px': net.input_px, 'channels': net.channels,
              'metadata': net.metadata}
    arrays = {}
    for name, (w, b) in net.weights.items():
        arrays[name + '.w'] = w.astype(np.float16)
        arrays[name + '.b'] = b.astype(np.float32)
    if net.quantized:
        arrays[QUANTIZED] = np.frombuffer(net.quantized, np.uint8)
    write_npz(path, header, arrays)


def is_convnet(path: str | Path) -> bool:
    """Whether `path` is a network written by `save_convnet` (not a part model)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return 'header' in data.files and \
                json.loads(str(data['header'])).get('format') == FORMAT
    except NPZ_ERRORS:
        return False


def load_convnet(path: str | Path, precision: str = 'fp32') -> ConvNet:
    """Read a network written by `save_convnet`, to run at `precision` (`ConvNet.precision`);
    ValueError naming the file when it is not one or cannot run so."""
    path = Path(path)
    arrays = read_npz(path, 'network model')
    try:
        header = json.loads(str(arrays.pop('header')))
    except (KeyError, ValueError) as exc:
        raise ValueError(f'{path}: not a network model (no header: {exc})') from exc
    if header.get('format') != FORMAT:
        raise ValueError(f'{path}: not a network model (format {header.get("format")!r}, '
                         f'expected {FORMAT!r})')
    weights = {}
    for name in layer_names():
        if name + '.w' not in arrays or name + '.b' not in arrays:
            raise ValueError(f'{path}: no weights for layer {name!r}')
        weights[name] = (arrays[name + '.w'].astype(np.float32),
                         arrays[name + '.b'].astype(np.float32))
    try:
        return ConvNet(tuple(header['joint_names']), tuple(header['mirror']),
                       int(header['input_px']), weights, dict(header.get('metadata', {})),
                       str(header.get('channels', 'rgb')),
                       arrays[QUANTIZED].tobytes() if QUANTIZED in arrays else b'', precision)
    except (KeyError, TypeError) as exc:
        raise ValueError(f'{path}: bad network header ({exc})') from exc
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None
