"""The photograph network's heat maps as a colour unary term of the 4D-DPM's tree inference.

The part model's colour filters are HOG templates learned from renders; on real photographs
they place few joints (the models' README). The photograph network (`core.convnet`) learned
real appearance instead. `NetUnary` adds, to every filter response of part i at a cell,

    weight * max(log p_j(cell), floor)

where p_j is the network's softmax over its grid for the joint j of the same name, read at the
cell's centre (bilinear between the network's cells), and scales the model's colour filters by
`hog_weight` (0: the network is the whole colour unary; 1: the HOG filters as trained). The
tree, its springs, its co-occurrence biases and the depth filters are unchanged, so the search
is still the exact optimum of Yang & Ramanan's score with one more unary per part (Chen &
Yuille 2014 put a network's part scores into a tree model the same way). A part the network
does not know gets nothing from it. `floor` keeps a cell the network rules out from vetoing a
pose the rest of the model supports.

The network reads the search's crop once per frame (`maps`), padded to a square; each pyramid
level then samples those maps at its filter positions' centres with one affine warp
(`level_unary`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.convnet import STRIDE, ConvNet, valid_scales
from pose4d_ros.core.hog import N_FEATURES, Level


@dataclass(frozen=True)
class NetMaps:
    """The network's maps of one frame's crop: (cells, cells, J) float32 `log p - floor`, at
    least 0; `transform` (2, 3) from full-image pixels to network input pixels."""

    values: NDArray[np.float32]
    transform: NDArray[np.float64]


@dataclass(frozen=True)
class UnaryConfig:
    """How the network enters the part model's score (see the module docstring).

    Attributes
    ----------
    weight : factor on the network's log-probability in a part's unary.
    hog_weight : factor on the model's colour HOG filters (the depth filters keep theirs).
        `weight` 4 and `hog_weight` 1 were chosen on validation for the shipped `rgbd_14` and
        `lspet_convnet` (`make results`' colour_net job, `docs/results/colour_net.json`: the
        best on LSPET photographs among the weightings losing at most 0.5 of average7 on
        `valid30`, `valid30_msr` and `valid60_people3`; chosen again for the network
        fine-tuned on renders in their rooms, weight 16 losing 1.1 on `valid60_people3`; and
        for `rgbd_14` retrained with mounted-camera renders, where the rule now also keeps
        `valid60_people2` and the tracking guard, which refuses weight 16: 6.9 false skeletons
        per 1000 frames there against 0 at weight 4).
    floor : log-probability below which a cell scores no worse.
    scales : the network's reading scales of the crop (`ConvNet.heat_maps`).
    mirror : the crop's mirror image read too and the maps averaged (twice the network's
        work). Off, chosen on validation for its cost (int8 network at weight 4, HOG weight 1;
        `rgbd_kf_ik` average7 on `valid30` / `valid30_msr`, LSPET 8501-9000 PCK@0.2 by the
        colour channel alone, the pipeline's CPU p50 a frame on `valid30`): with the mirror
        98.45 / 94.77, 65.5, 16.4 ms; without 98.39 / 94.71, 64.4, 11.4 ms (no network:
        98.75 / 93.46, 12.9, 6.6 ms).
    input_px : the size the crop is read at, pixels (a multiple of 32; 0 = the network's own
        `input_px`): the network is fully convolutional.
    masked : the network reads the crop blanked outside the person's mask, as the part model
        does (a model trained on masked frames); off: the camera's crop as it is, the
        person's surroundings included, as the network's photographs show them.
    score_scale, score_offset : the pose's score handed on (`Pose.score`) is
        ``score_scale * s + score_offset``, s the part model's score at the pose the network
        chose: the network pulls the parts off the model's own maxima, more so where the
        filters see no person, so s runs far lower than the model's maxima do (real Xtion
        frames, `lab_walk`: people's poses median -2.2, 5-95 % -16 to 4; poses on furniture
        median -13.9) and the tracker's thresholds (`core.people.TrackingConfig`: birth 5,
        trust 7, emerging 3, set on the model's maxima) would refuse nearly everyone. The
        linear map puts s = -3 at the birth score, s = 3 at the trust score and s = -9 at the
        emerging score. Chosen on validation: first for the float network read with its
        mirror image, `valid60_people2` (`rgbd_kf_ik` average7 / MOTA / false skeletons per
        1000 frames) 83.63 / 0.871 / 0 uncalibrated (129 missed person-frames per 1000: people
        never confirmed), 87.61 / 0.956 / 18 with s = -5 at the birth score (offset 20/3),
        87.70 / 0.928 / 74 with s = -8; `valid60_people3` 87.01 / 0.971 / 0. Then for the 8-bit
        network read once, the default (`pose4d eval DIR --no-single-frame --config
        unary.score_offset=O`): offset 20/3 `valid60_people2` 87.60 / 0.895 / 102.8,
        `valid60_people3` 86.59 / 0.970 / 0; offset 6 (s = -3 at birth) 87.57 / 0.920 / 51.4
        and 86.71 / 0.970 / 0; 5.67 (s = -2) the same as 6. On the real development recording
        lab_walk (labelled people found of 228 / ghosts): 20/3 138 / 30, 6 143 / 26, 5 79 / 9
        (people refused): 6 shipped.
    """

    weight: float = 4.0
    hog_weight: float = 1.0
    floor: float = -10.0
    scales: tuple[float, ...] = (1.0,)
    mirror: bool = False
    input_px: int = 0
    masked: bool = True
    score_scale: float = 1.0 / 3.0
    score_offset: float = 6.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.score_scale) and self.score_scale > 0
                and np.isfinite(self.score_offset)):
            raise ValueError(f'unary score_scale must be > 0 and score_offset finite, got '
                             f'{self.score_scale}, {self.score_offset}')
        if not (np.isfinite(self.weight) and self.weight >= 0):
            raise ValueError(f'unary weight must be >= 0, got {self.weight}')
        if not (np.isfinite(self.hog_weight) and self.hog_weight >= 0):
            raise ValueError(f'unary hog_weight must be >= 0, got {self.hog_weight}')
        if not (np.isfinite(self.floor) and self.floor < 0):
            raise ValueError(f'unary floor must be a log-probability < 0, got {self.floor}')
        if self.input_px < 0 or self.input_px % 32:
            raise ValueError(f'unary input_px must be 0 or a multiple of 32, got '
                             f'{self.input_px}')
        if not valid_scales(self.scales):
            raise ValueError(f'unary scales must include 1 and lie within 0.25..4, got '
                             f'{self.scales}')


@dataclass(frozen=True)
class NetUnary:
    """A photograph network (`core.convnet`) as a colour unary of a part model."""

    net: ConvNet
    config: UnaryConfig = UnaryConfig()

    def __post_init__(self) -> None:
        if self.config.input_px and self.config.input_px != self.net.input_px:
            object.__setattr__(self, 'net', replace(self.net, input_px=self.config.input_px))

    def calibrated(self, score: float) -> float:
        """A pose's part-model score on the scale of the model's own maxima (`UnaryConfig`'s
        `score_scale`, `score_offset`); unchanged at `weight` 0 (no pull off the maxima)."""
        c = self.config
        return c.score_scale * score + c.score_offset if c.weight > 0 else score

    def joints_of(self, part_names: tuple[str, ...]) -> NDArray[np.int64]:
        """For each part, the index of the network's joint of the same name (-1: none)."""
        index = {n: i for i, n in enumerate(self.net.joint_names)}
        return np.array([index.get(n, -1) for n in part_names], np.int64)

    def filter_matrix(self, wmat: NDArray[np.float32], groups: int) -> NDArray[np.float32]:
        """The model's filter matrix (`PartModel.filter_matrix`, `groups` =
        `PartModel.n_channels` groups of HOG features a cell) with its colour features (each
        cell's first `N_FEATURES`) scaled by `hog_weight`."""
        if self.config.hog_weight == 1.0:
            return wmat
        w = wmat.reshape(wmat.shape[0], -1, groups * N_FEATURES).copy()
        w[:, :, :N_FEATURES] *= np.float32(self.config.hog_weight)
        return np.ascontiguousarray(w.reshape(wmat.shape))

    def maps(self, color: NDArray, box: tuple[int, int, int, int]) -> NetMaps:
        """The network's maps of `color`'s crop `box` = (x0, y0, x1, y1) pixels (RGB; a grey
        image is read as three equal channels)."""
        x0, y0, x1, y1 = box
        crop = np.asarray(color)[y0:y1, x0:x1]
        if crop.ndim == 2:
            crop = np.repeat(crop[:, :, None], 3, axis=2)
        crop = np.ascontiguousarray(crop[:, :, :3], dtype=np.uint8)
        logp, m = self.net.heat_maps(crop, self.config.scales, mirror=self.config.mirror)
        values = np.maximum(logp - np.float32(self.config.floor), 0).transpose(1, 2, 0)
        m = m.copy()
        m[:, 2] -= m[:, :2] @ np.array([x0, y0], np.float64)  # from full-image pixels
        return NetMaps(np.ascontiguousarray(values, np.float32), m)

    def level_unary(self, maps: NetMaps, level: Level, filter_shape: tuple[int, int],
                    ny: int, nx: int) -> NDArray[np.float32]:
        """(J, ny, nx) float32: `weight` x the network's log-probability (floored) of each
        joint at the centre of each of the level's (ny, nx) filter positions."""
        # filter position (row, col) -> full-image pixel (`Level.cell_to_pixel`, linear)
        # -> network input pixel (`maps.transform`, no rotation) -> network cell
        u0, v0 = level.cell_to_pixel(np.float64(0), np.float64(0), filter_shape)
        u1, v1 = level.cell_to_pixel(np.float64(1), np.float64(1), filter_shape)
        m = maps.transform
        ax = m[0, 0] * (u1 - u0) / STRIDE
        bx = ((m[0, 0] * u0 + m[0, 2]) + 0.5) / STRIDE - 0.5
        ay = m[1, 1] * (v1 - v0) / STRIDE
        by = ((m[1, 1] * v0 + m[1, 2]) + 0.5) / STRIDE - 0.5
        a = np.array([[ax, 0.0, bx], [0.0, ay, by]])
        out = cv2.warpAffine(maps.values, a, (nx, ny), flags=cv2.INTER_LINEAR |
                             cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                             borderValue=0)
        if out.ndim == 2:
            out = out[:, :, None]
        c = self.config
        return (out.transpose(2, 0, 1) + np.float32(c.floor)) * np.float32(c.weight)
