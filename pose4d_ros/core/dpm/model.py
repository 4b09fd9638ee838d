"""The 4D-DPM part model: Yang & Ramanan's flexible mixture of parts with a depth channel.

Yang & Ramanan, "Articulated human detection with flexible mixtures of parts" (PAMI 2013),
eq. (1)-(3): a pose is a location l_i and a mixture type t_i per part i of a tree, scored by

    S(I, l, t) = sum_i b_i^{t_i} + sum_{ij} b_ij^{t_i, t_j}                 (co-occurrence)
               + sum_i w_i^{t_i} . phi(I, l_i)                              (appearance)
               + sum_{ij} w_ij^{t_j} . psi(l_j - l_i - a_ij^{t_j})          (springs)

with psi(d) = -[d_x, d_x^2, d_y, d_y^2]. The 4D-DPM of Martinez Berti et al. gives every part
type one colour filter and one depth filter: phi is the HOG of colour stacked with the HOG of
depth, so w_i^{t} = [w_colour; w_depth] (`channels='rgbd'`); `channels='rgb'` drops the depth
filters and is the Yang & Ramanan baseline, same code. As in Yang & Ramanan's released code,
the spring and its anchor depend on the child's type, and the co-occurrence bias on both types;
the root's unary bias b_0^{t} sits in `bias[0, 0, t]` (the per-part unary biases of eq. (1) are
absorbed by the pairwise ones, as in that code).

Geometry: a part location is the top-left cell of its filter in a padded HOG level (all filters
have one shape); anchors and spring offsets are in cells of that level. The level that holds a
person at the model's canonical size is found from the person's scale: `canonical_scale_px`
level pixels per `scale_length_m` metres of body (from depth), or per the same length measured
on the joints (see `training.dpm.samples.person_scale`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.files import read_npz, write_npz
from pose4d_ros.core.hog import N_FEATURES
from pose4d_ros.core.refine import PartRefiner

CHANNELS = ('rgb', 'rgbd')
DEPTH_ENCODINGS = ('float', 'u8')
FORMAT_VERSION = 1

# The depth look-up (window half-size in metres on the body, quantile) of a part that has none
# learned: about the median of a 3-pixel window at 3 m in a 320x240 image
DEFAULT_DEPTH_LOOKUP = (0.03, 0.5)


@dataclass(frozen=True)
class PartModel:
    """A trained mixture-of-parts model (see the module docstring for the score).

    Attributes
    ----------
    part_names : P part names (skeleton names), parents before children.
    parents : P parent indices, -1 for the root (part 0).
    channels : 'rgbd' (colour and depth filter per type) or 'rgb' (colour only).
    sbin : HOG cell size, pixels of the level image.
    filters : (P, K, fh, fw, C) float32; C = 32 (rgb) or 64 (colour 0..31, depth 32..63).
    springs : (P, K, 4) float32 [w_dx, w_dx2, w_dy, w_dy2] per (child part, child type), cells;
        row 0 (the root) is unused. w_dx2, w_dy2 > 0.
    anchors : (P, K, 2) int32 rest offset (dx, dy) of the child's filter from its parent's,
        cells, per child type; row 0 unused.
    bias : (P, K, K) float32; bias[i, l, k] = b(parent type l, child type k) for part i > 0;
        bias[0, 0, k] = the root's bias for type k (bias[0, 1:] unused).
    canonical_scale_px : the person scale, in level pixels, at which the model was trained.
    scale_length_m : metres of body that make one person scale (depth -> scale).
    scale_range_px : (lo, hi) person scale in source pixels seen in training; a search without
        depth covers it.
    depth_encoding : 'float' or 'u8' (see `core.hog.depth_image`); '' for rgb.
    depth_range_m : (near, far) metres for the depth encoding.
    calibration : (P, 3) float32 logistic coefficients: confidence of part i =
        sigmoid(c0 * local_score + c1 * pose_score + c2).
    masked_input : trained on frames whose colour and depth were blanked outside the person's
        foreground mask (as the foreground stage publishes them); the detector then blanks its
        input outside the mask it is given, so raw and pre-masked frames give the same answer.
    metadata : free-form strings (data, command, seed, time, git commit, ...).
    depth_offset_m : (P,) float32 how far behind the visible surface each part's joint centre
        lies, metres (rgbd models: learned with the calibration); None = on the surface.
    search_range_px : (lo, hi) person scales in source pixels that the search without depth
        covers: the middle 90 % of the training people's scales with a margin (`train`);
        None = `scale_range_px`.
    depth_lookup : (P, 2) float32 how each part's depth is read (`camera.lift_depth`): the
        window's half-size in metres and the quantile of its depths (rgbd models: chosen with
        the calibration); None = the median of a 3-pixel window for every part.
    refiner : the learned correction of each detected part's pixel and depth (`core.refine`,
        fitted by `pose4d train --refine`); None = none.
    scale_prior : score per octave of person scale added when the search without depth ranks
        the poses of its levels (a model whose filters also fire on texture at small scales
        prefers people of the size it was trained on; chosen by the calibration, 0 = none).
    """

    part_names: tuple[str, ...]
    parents: tuple[int, ...]
    channels: str
    sbin: int
    filters: NDArray[np.float32]
    springs: NDArray[np.float32]
    anchors: NDArray[np.int32]
    bias: NDArray[np.float32]
    canonical_scale_px: float
    scale_length_m: float
    scale_range_px: tuple[float, float]
    depth_encoding: str = ''
    depth_range_m: tuple[float, float] = (0.5, 4.5)
    calibration: NDArray[np.float32] | None = None
    masked_input: bool = False
    metadata: Mapping[str, str] = field(default_factory=dict)
    depth_offset_m: NDArray[np.float32] | None = None
    depth_lookup: NDArray[np.float32] | None = None
    search_range_px: tuple[float, float] | None = None
    refiner: PartRefiner | None = None
    scale_prior: float = 0.0

    def __post_init__(self) -> None:
        p = len(self.part_names)
        if len(self.parents) != p:
            raise ValueError(f'{p} part names but {len(self.parents)} parents')
        if p == 0 or self.parents[0] != -1:
            raise ValueError(f'part 0 must be the root (parent -1), got parents {self.parents}')
        for i, par in enumerate(self.parents[1:], start=1):
            if not 0 <= par < i:
                raise ValueError(f'parent {par} of part {i} must come before it')
        if self.channels not in CHANNELS:
            raise ValueError(f'channels must be one of {CHANNELS}, got {self.channels!r}')
        if self.channels == 'rgbd' and self.depth_encoding not in DEPTH_ENCODINGS:
            raise ValueError(f'an rgbd model needs depth_encoding in {DEPTH_ENCODINGS}, '
                             f'got {self.depth_encoding!r}')
        if self.sbin < 2:
            raise ValueError(f'sbin must be >= 2, got {self.sbin}')
        f = self.filters
        if f.ndim != 5 or f.shape[0] != p or f.shape[4] != self.n_channels * N_FEATURES:
            raise ValueError(f'filters must be (P={p}, K, fh, fw, {self.n_channels * N_FEATURES})'
                             f', got {f.shape}')
        k = f.shape[1]
        for name, arr, shape in (('springs', self.springs, (p, k, 4)),
                                 ('anchors', self.anchors, (p, k, 2)),
                                 ('bias', self.bias, (p, k, k))):
            if arr.shape != shape:
                raise ValueError(f'{name} must have shape {shape}, got {arr.shape}')
        if self.calibration is not None and self.calibration.shape != (p, 3):
            raise ValueError(f'calibration must have shape ({p}, 3), got '
                             f'{self.calibration.shape}')
        offset = self.depth_offset_m
        if offset is not None and (offset.shape != (p,) or not (np.abs(offset) < 1.0).all()):
            raise ValueError(f'depth_offset_m must be ({p},) metres within +-1, got '
                             f'{np.asarray(offset).tolist()}')
        if self.search_range_px is not None and not (
                0 < self.search_range_px[0] < self.search_range_px[1]):
            raise ValueError(f'search_range_px must be (lo, hi) with 0 < lo < hi, got '
                             f'{self.search_range_px}')
        lookup = self.depth_lookup
        if lookup is not None and (lookup.shape != (p, 2) or not (
                (lookup[:, 0] > 0) & (lookup[:, 0] <= 0.5)
                & (lookup[:, 1] >= 0) & (lookup[:, 1] <= 1)).all()):
            raise ValueError(f'depth_lookup must be ({p}, 2): a radius in (0, 0.5] metres and '
                             f'a quantile in [0, 1] per part, got {np.asarray(lookup).tolist()}')
        if p > 1 and not ((self.springs[1:, :, 1] > 0).all()
                          and (self.springs[1:, :, 3] > 0).all()):
            raise ValueError('spring weights w_dx2 and w_dy2 must be > 0')
        if not (np.isfinite(self.scale_prior) and abs(self.scale_prior) <= 100):
            raise ValueError(f'scale_prior must be a finite score within +-100, got '
                             f'{self.scale_prior}')
        if not (self.canonical_scale_px > 0 and self.scale_length_m > 0):
            raise ValueError('canonical_scale_px and scale_length_m must be > 0')
        for name, arr in (('filters', f), ('springs', self.springs), ('bias', self.bias)):
            if not np.isfinite(arr).all():
                raise ValueError(f'{name} holds NaN or inf')

    @property
    def n_parts(self) -> int:
        return len(self.part_names)

    @property
    def n_types(self) -> int:
        return int(self.filters.shape[1])

    @property
    def filter_shape(self) -> tuple[int, int]:
        return int(self.filters.shape[2]), int(self.filters.shape[3])

    @property
    def n_channels(self) -> int:
        """Channel groups of 32 HOG features: 1 (rgb) or 2 (rgbd)."""
        return 2 if self.channels == 'rgbd' else 1

    def filter_matrix(self) -> NDArray[np.float32]:
        """(P*K, fh*fw*C) float32: every filter as a row, part-major (row i*K + k), for the
        one-GEMM response of a level."""
        p, k = self.n_parts, self.n_types
        return np.ascontiguousarray(self.filters.reshape(p * k, -1), dtype=np.float32)


def colour_channel(model: PartModel) -> PartModel:
    """An rgbd model's colour channel alone, for frames without depth (photographs): each
    filter's colour half w_colour (the depth half w_depth would only score the constant
    features of a missing depth image, so it is dropped), the same tree, springs and type
    biases, searched without depth over the scales of its training people
    (`PartModel.search_range_px`). What depth gave is gone: the depth-predicted scale, the 3-D
    look-up and offsets, the part refiner (it probes depth); a model trained on masked frames
    still sees a whole photograph, clutter included."""
    if model.channels != 'rgbd':
        return model
    return replace(model, channels='rgb', filters=np.ascontiguousarray(
        model.filters[..., :N_FEATURES]), depth_encoding='', depth_offset_m=None,
        depth_lookup=None, refiner=None,
        metadata={**model.metadata, 'channels_used': 'colour alone (of an rgbd model)'})


_ARRAYS = ('filters', 'springs', 'anchors', 'bias')
_OPTIONAL = ('calibration', 'depth_offset_m', 'depth_lookup')  # float32 arrays a model may have
_REFINER = 'refiner_'  # prefix of the refiner's arrays (`PartRefiner.arrays`)


def save_model(model: PartModel, path: str | Path) -> None:
    """Write a model as .npz (to a temporary name, renamed when complete)."""
    path = Path(path)
    header = {
        'format_version': FORMAT_VERSION,
        'part_names': list(model.part_names), 'parents': list(model.parents),
        'channels': model.channels, 'sbin': model.sbin,
        'canonical_scale_px': model.canonical_scale_px, 'scale_length_m': model.scale_length_m,
        'scale_range_px': list(model.scale_range_px), 'depth_encoding': model.depth_encoding,
        'depth_range_m': list(model.depth_range_m), 'masked_input': model.masked_input,
        'metadata': dict(model.metadata),
    }
    if model.search_range_px is not None:
        header['search_range_px'] = list(model.search_range_px)
    if model.scale_prior:
        header['scale_prior'] = model.scale_prior
    arrays = {name: getattr(model, name) for name in _ARRAYS}
    for name in _OPTIONAL:
        if getattr(model, name) is not None:
            arrays[name] = getattr(model, name)
    if model.refiner is not None:
        arrays.update({_REFINER + k: v for k, v in model.refiner.arrays().items()})
    write_npz(path, header, arrays)


def load_model(path: str | Path) -> PartModel:
    """Read a model written by `save_model`; ValueError naming the file when it is not one."""
    path = Path(path)
    contents = read_npz(path, 'part model')
    missing = [k for k in ('header', *_ARRAYS) if k not in contents]
    if missing:
        raise ValueError(f'{path}: not a part model, missing {missing}')
    try:
        header = json.loads(str(contents['header']))
        if header.get('format_version') != FORMAT_VERSION:
            raise ValueError(f"format version {header.get('format_version')}, "
                             f'expected {FORMAT_VERSION}')
        return PartModel(
            part_names=tuple(str(n) for n in header['part_names']),
            parents=tuple(int(p) for p in header['parents']),
            channels=str(header['channels']), sbin=int(header['sbin']),
            filters=contents['filters'].astype(np.float32),
            springs=contents['springs'].astype(np.float32),
            anchors=contents['anchors'].astype(np.int32),
            bias=contents['bias'].astype(np.float32),
            canonical_scale_px=float(header['canonical_scale_px']),
            scale_length_m=float(header['scale_length_m']),
            scale_range_px=tuple(float(x) for x in header['scale_range_px']),
            depth_encoding=str(header['depth_encoding']),
            depth_range_m=tuple(float(x) for x in header['depth_range_m']),
            **{name: contents[name].astype(np.float32) for name in _OPTIONAL
               if name in contents},
            masked_input=bool(header.get('masked_input', False)),
            search_range_px=(tuple(float(x) for x in header['search_range_px'])
                             if 'search_range_px' in header else None),
            metadata={str(k): str(v) for k, v in header.get('metadata', {}).items()},
            scale_prior=float(header.get('scale_prior', 0.0)),
            refiner=PartRefiner.from_arrays(
                {k[len(_REFINER):]: v for k, v in contents.items() if k.startswith(_REFINER)})
            if _REFINER + 'groups' in contents else None,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f'{path}: bad part model: {exc}') from exc
