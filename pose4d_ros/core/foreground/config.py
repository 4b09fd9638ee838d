"""The foreground's parameters, one dataclass per job (`RegionConfig`: the 8-bit depth and its
stable regions; `FloorConfig`: the floor plane; `PersonConfig`: the person rules; `MaskConfig`:
the mask's completion and working size), joined in `ForegroundConfig` with the same flat field
names (the nodes' parameters and YAML name them so), and the result of a frame."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from numpy.typing import NDArray

# Reasons given when no person is found.
REASON_OK = ''
REASON_TOO_SMALL = 'image too small'
REASON_NO_DEPTH = 'no valid depth'
REASON_NO_REGION = 'no stable region'
REASON_NO_PERSON = 'no region of person size'



def _integers(config: object) -> None:
    """ValueError unless every `int` field holds an int (not a bool)."""
    for f in fields(config):  # type: ignore[arg-type]
        value = getattr(config, f.name)
        if f.type == 'int' and (not isinstance(value, int) or isinstance(value, bool)):
            raise ValueError(f'{f.name} must be an integer, got {value!r}')


@dataclass(frozen=True)
class RegionConfig:
    """The 8-bit depth image and its stable regions (`ForegroundConfig` describes the fields)."""

    depth_near_m: float = 0.4
    depth_far_m: float = 4.5
    mser_delta: int = 6
    mser_min_area_px: int = 60
    max_region_area_px: int = 30000
    mser_max_variation: float = 0.5
    connectivity: int = 8
    tree_step: int = 2

    def __post_init__(self) -> None:
        _integers(self)
        self._check_regions()

    def _check_regions(self) -> None:
        if not (math.isfinite(self.depth_near_m) and math.isfinite(self.depth_far_m)
                and 0.0 <= self.depth_near_m < self.depth_far_m):
            raise ValueError(f'need 0 <= depth_near_m < depth_far_m, got depth_near_m='
                             f'{self.depth_near_m}, depth_far_m={self.depth_far_m}')
        if not 1 <= self.mser_delta <= 64:
            raise ValueError(f'mser_delta must be in [1, 64] levels, got {self.mser_delta}')
        if not 1 <= self.mser_min_area_px < self.max_region_area_px:
            raise ValueError(f'need 1 <= mser_min_area_px < max_region_area_px, got '
                             f'mser_min_area_px={self.mser_min_area_px}, '
                             f'max_region_area_px={self.max_region_area_px}')
        if not self.mser_max_variation > 0:
            raise ValueError(f'mser_max_variation must be positive, got {self.mser_max_variation}')
        if self.tree_step not in (1, 2, 3, 4):
            raise ValueError(f'tree_step must be 1, 2, 3 or 4, got {self.tree_step}')
        if self.connectivity not in (4, 8):
            raise ValueError(f'connectivity must be 4 or 8, got {self.connectivity}')

    @property
    def metres_per_level(self) -> float:
        """Depth step of one 8-bit level, metres."""
        return (self.depth_far_m - self.depth_near_m) / 254.0


def _ordered(config: object, *pairs: tuple[str, str]) -> None:
    """ValueError unless 0 <= lo < hi for every (lo, hi) pair of field names."""
    for lo, hi in pairs:
        a, b = getattr(config, lo), getattr(config, hi)
        if not 0.0 <= a < b:
            raise ValueError(f'need 0 <= {lo} < {hi}, got {lo}={a}, {hi}={b}')


def _at_least_one(config: object, *names: str) -> None:
    for name in names:
        if getattr(config, name) < 1:
            raise ValueError(f'{name} must be >= 1, got {getattr(config, name)}')


def _not_negative(config: object, *names: str) -> None:
    for name in names:
        if not getattr(config, name) >= 0:
            raise ValueError(f'{name} must be >= 0, got {getattr(config, name)}')


@dataclass(frozen=True)
class PersonConfig:
    """The person rules and the regions' scores (`ForegroundConfig` describes the fields)."""

    person_min_height_m: float = 0.8
    person_max_height_m: float = 2.3
    person_min_cut_height_m: float = 0.4
    person_min_width_m: float = 0.15
    person_max_width_m: float = 2.0
    person_min_area_m2: float = 0.1
    person_max_area_m2: float = 0.8
    person_max_fill: float = 0.7
    border_penalty: float = 2.0
    merge_slack: float = 2.0
    person_min_top_m: float = 0.9
    person_max_top_m: float = 2.5
    person_min_bent_top_m: float = 0.5
    person_max_bottom_m: float = 1.0
    person_max_extent_m: float = 1.0
    edge_rows: int = 3
    max_candidates: int = 6
    occluder_gap_m: float = 0.3
    second_look: bool = True
    stability_weight: float = 50.0
    previous_bonus: float = 0.5

    def __post_init__(self) -> None:
        _integers(self)
        self._check_person()

    def _check_person(self) -> None:
        _ordered(self, ('person_min_height_m', 'person_max_height_m'),
                 ('person_min_cut_height_m', 'person_max_height_m'),
                 ('person_min_area_m2', 'person_max_area_m2'),
                 ('person_min_top_m', 'person_max_top_m'),
                 ('person_min_width_m', 'person_max_width_m'))
        if not self.person_max_extent_m > 0:
            raise ValueError(f'person_max_extent_m must be positive, got '
                             f'{self.person_max_extent_m}')
        if not self.person_max_bottom_m >= 0:
            raise ValueError(f'person_max_bottom_m must be >= 0, got {self.person_max_bottom_m}')
        if not self.merge_slack >= 1.0:
            raise ValueError(f'merge_slack must be >= 1, got {self.merge_slack}')
        _at_least_one(self, 'max_candidates', 'edge_rows')
        if not self.occluder_gap_m >= 0:
            raise ValueError(f'occluder_gap_m must be >= 0, got {self.occluder_gap_m}')
        if not 0.0 < self.person_max_fill <= 1.0:
            raise ValueError(f'person_max_fill must be in (0, 1], got {self.person_max_fill}')
        _not_negative(self, 'stability_weight', 'previous_bonus', 'border_penalty',
                      'person_min_bent_top_m')

    @property
    def min_cut_area_m2(self) -> float:
        """Smallest surface of a region cut by the image's bottom edge, square metres."""
        return self.person_min_area_m2 * self.person_min_cut_height_m / self.person_min_height_m


@dataclass(frozen=True)
class FloorConfig:
    """The floor plane's RANSAC fit (`ForegroundConfig` describes the fields)."""

    floor_remove: bool = True
    floor_rows_fraction: float = 0.5
    floor_sample_step: int = 4
    floor_iterations: int = 64
    floor_inlier_m: float = 0.004
    floor_tolerance_m: float = 0.02
    floor_max_tilt_deg: float = 45.0
    floor_min_height_m: float = 0.3
    floor_max_height_m: float = 3.0
    floor_min_inliers: int = 40
    floor_max_below: float = 0.25
    seed: int = 0

    def __post_init__(self) -> None:
        _integers(self)
        self._check_floor()

    def _check_floor(self) -> None:
        _ordered(self, ('floor_min_height_m', 'floor_max_height_m'))
        if not 0.0 < self.floor_rows_fraction <= 1.0:
            raise ValueError(f'floor_rows_fraction must be in (0, 1], got '
                             f'{self.floor_rows_fraction}')
        _at_least_one(self, 'floor_sample_step', 'floor_iterations', 'floor_min_inliers')
        for name in ('floor_inlier_m', 'floor_tolerance_m'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)}')
        if not 0.0 < self.floor_max_tilt_deg < 90.0:
            raise ValueError(f'floor_max_tilt_deg must be in (0, 90), got '
                             f'{self.floor_max_tilt_deg}')
        if not self.floor_max_below >= 0.0:
            raise ValueError(f'floor_max_below must be >= 0, got {self.floor_max_below}')


@dataclass(frozen=True)
class MaskConfig:
    """The mask's completion and the working resolution (`ForegroundConfig` describes the
    fields)."""

    close_px: int = 5
    fill_holes: bool = False
    working_height_px: int = 240
    grow_min_above_m: float = 0.06
    grow_max_above_m: float = 0.85
    grow_step_m: float = 0.05
    grow_px: int = 4

    def __post_init__(self) -> None:
        _integers(self)
        self._check_mask()

    def _check_mask(self) -> None:
        _at_least_one(self, 'working_height_px')
        if not 0 <= self.close_px <= 31:
            raise ValueError(f'close_px must be in [0, 31], got {self.close_px}')
        _not_negative(self, 'grow_min_above_m', 'grow_max_above_m', 'grow_px')
        if not self.grow_step_m > 0:
            raise ValueError(f'grow_step_m must be positive, got {self.grow_step_m}')


@dataclass(frozen=True)
class ForegroundConfig(MaskConfig, FloorConfig, PersonConfig, RegionConfig):
    """Parameters of `segment`; defaults tuned on the synthetic training set.

    Tuning (``foreground_tune.py`` in the project notes; synthetic training set, 1536 frames of
    UTKinect subjects s01-s06 in random rooms, 320x240): coordinate search of one parameter at
    a time over a grid, every second frame, maximising the mean mask IoU, until no change
    helped; then the person rules and score weights were searched on the stored candidate
    parts of all frames, and one more coordinate round changed nothing. Mean IoU on the
    training set 0.932 (median 0.947, 96.2 % of frames above 0.8); on the unseen test set
    (s07-s08, 400 frames) 0.912 (median 0.944, 86.0 % above 0.8). What mattered: floor
    removal (without it 0.38), a thin floor band (`floor_tolerance_m` 2 cm: 5 cm loses the
    shoes, 0.925), the closing into no-reading edge pixels (`close_px` 0: 0.883), the depth
    splits (`occluder_gap_m` 0 and no extent rule: 0.859), and `person_max_area_m2` (0.7 was
    best on the training set, 0.80 is kept for a margin above the largest training person,
    0.73 m^2, at a cost of 0.004 IoU there; 0.9 and above: 0.915). Flat on the training set:
    `max_region_area_px` 15000-40000 (30000 keeps people nearer than 2 m), `mser_max_variation`
    0.25-2, `stability_weight` 10-50, `mser_delta` 6-8 (4: 0.931, 2: 0.918; grid runs on every
    second frame). `tree_step` 2 costs 0.002 IoU and saves about 40 % of the time.

    Attributes
    ----------
    depth_near_m, depth_far_m : depth range mapped to the 8-bit image, metres (near -> 255,
        far -> 1, everything else 0).
    mser_delta : MSER stability step, 8-bit levels (one level = (far - near) / 254 metres;
        6 levels = 10 cm with the defaults).
    mser_min_area_px : smallest region, pixels (at the input resolution).
    max_region_area_px : the trained background area threshold: larger regions are
        background, pixels (at the input resolution).
    mser_max_variation : the paper's stability score: largest relative area growth over
        `mser_delta` levels further away for a region to be stable.
    connectivity : pixel neighbourhood of the regions, 4 or 8.
    tree_step : the region tree is built on every `tree_step`-th pixel of each row and
        column (1 = all; 2 = four times faster); chosen regions are traced at full
        resolution.
    person_min_height_m, person_max_height_m : height of a person region, metres (box height
        times median depth over fy).
    person_min_cut_height_m : smallest height of a region cut by the image's bottom edge (a
        person nearer than the camera sees whole: head and shoulders down to the edge),
        metres; its smallest surface is `person_min_area_m2` in the same proportion, and its
        bottom rows are the edge, not its feet, so the bottom rule does not apply to it.
    person_min_width_m, person_max_width_m : width, metres (box width times depth over fx).
    person_min_area_m2, person_max_area_m2 : surface of a person region seen from the
        camera, square metres (pixels times depth squared over fx fy).
    person_max_fill : largest fraction of its box a person region fills (furniture and wall
        pieces fill their boxes).
    border_penalty : score taken from a region that touches the left or right image border.
    merge_slack : factor on the upper person bounds for whole regions, before they are split
        at depth gaps (a region may hold an occluder or furniture besides the person).
    max_candidates : regions (best first) whose pixels are examined.
    person_min_top_m, person_max_top_m : height above the floor of a person part's top rows
        (head, or hands raised), metres; only with a floor.
    person_min_bent_top_m : a part whose box overlaps a box of the previous frame's people by
        more than 0.3 (intersection over union) may be that person bending or crouching (a
        pick-up, a bow): it passes with a cut person's height and surface
        (`person_min_cut_height_m`) and its top rows at least this high above the floor
        (only with a floor), metres; inf = the usual rules for everyone.
    person_max_bottom_m : largest height above the floor of its bottom rows (feet, or the top
        of an occluder hiding them), metres; only with a floor.
    person_max_extent_m : largest depth extent of a person part (5th to 95th percentile of
        its depths), metres; deeper regions are also split in two at Otsu's threshold.
    edge_rows : rows at the top and bottom of a part whose median height is its top/bottom.
    floor_remove : fit and drop the floor plane before MSER.
    floor_rows_fraction : lower fraction of the image rows searched for the floor.
    floor_sample_step : pixel stride of the RANSAC sample grid.
    floor_iterations : RANSAC hypotheses per frame.
    floor_inlier_m : RANSAC inlier distance at 1 m, metres; grows with depth squared (Kinect
        depth noise and quantisation do).
    floor_tolerance_m : pixels less than this above the floor plane are floor, metres.
    floor_max_tilt_deg : largest angle between the floor normal and the optical -y axis (the
        camera's pitch, about): 45, a camera on a wall above the heads looking down (the real
        lab recording's is pitched 29-30 degrees, and at 30 its floor was found in some frames
        and not in others). Chosen on validation renders from such a camera (`pose4d synth
        --camera-height 2.0 2.7 --camera-pitch 20 35`; `rgbd_kf_ik` average7 / MOTA at 30
        and 45: `valid30_high` 82.05 and 83.09, `valid60_people3_high` 79.07 / 0.895 and
        81.97 / 0.931, false skeletons per 1000 frames 29.2 and 1.4); the renders from a
        camera at chest height the same to the digit (`valid30`, `valid30_msr`,
        `valid60_people2`, `valid60_people3`).
    floor_min_height_m, floor_max_height_m : range of camera heights above the floor, metres.
    floor_min_inliers : fewest RANSAC inliers for a floor to be accepted.
    floor_max_below : a plane with more than this many sampled points below it (by over
        10 cm, `floor.FLOOR_BELOW_M`, or the inlier tolerance) per point on it is not the
        floor (a floor has nothing below it): a table top or seat near the camera may hold
        more of the lower image than the floor does, and taken for the floor it cuts the
        person at its height (their legs dropped as floor). 0 = no such rule. Chosen on
        validation (`rgbd_kf_ik` average7, `pose4d eval --config
        foreground.floor_max_below=X`): 0 (before) / 0.25: valid30 98.50 / 98.85,
        valid30_msr 89.01 / 91.14 (a throw seen over a coffee table: 70 -> 88 on its
        videos), valid30_near 84.13 / 84.40; valid60_people2 87.47 / 87.27, its alone twins
        unchanged; 0.1 and 0.5 as 0.25 (within 0.01).
    occluder_gap_m : an empty depth gap wider than this inside the chosen region separates a
        nearer object (an occluder) from the person, metres; 0 disables the cut.
    second_look : `segment_people` looks again for people partly hidden by those found (their
        pixels left out; `occluded_rules`), where someone may be hidden: at a stream's start
        (no previous people), when someone of the previous frame is missing beside a person
        found (`segmentation._gone_beside`: not a region gone elsewhere, such as a wall's edge
        at the image's border found one frame in two), and while it finds someone
        (`ForegroundResult.behind`); a lone person in the open costs no second look. On,
        chosen on validation (`tools/people_sweep.py`, valid60_people2 and its alone twins,
        with the tracker's `trust_score`): two people MOTA 0.910 -> 0.953,
        average7 84.8 -> 86.6, false skeletons 0 -> 8 per 1000 frames; alone unchanged. (Off
        before: looking on every frame, with a lone person's best region trusted at once, it
        took a door behind a lone person for a second one.)
    close_px : size of the closing (ellipse, pixels) whose no-reading pixels join the mask;
        0 or 1 = none.
    fill_holes : fill holes of the mask that have no depth reading.
    grow_min_above_m, grow_max_above_m, grow_step_m, grow_px : the mask grows down from its
        pixels less than `grow_max_above_m` above the floor into the pixels below them whose
        depth runs on from theirs (within `grow_step_m` metres from one row to the next, on
        the working grid) and that stand at least `grow_min_above_m` above the floor, within
        `grow_px` columns beside its box (`mask.grow_down`: a leg seen from above runs into
        the floor's depth, and its region ended at the knees); `grow_min_above_m` 0 = none.
    stability_weight : a region's score is ``log(area) - stability_weight * variation -
        border_penalty * touches_side``.
    previous_bonus : with `previous`, score added to a region whose box overlaps the previous
        box by more than 0.3 (intersection over union); 0 = no temporal preference.
    seed : RANSAC random seed (the result is a function of the input).
    working_height_px : larger depth images are segmented on every f-th pixel of every f-th
        row, f the largest integer factor that keeps at least this many rows (640x480 and
        848x480 at 320x240 and 424x240), and the mask is brought back to full size: the
        parameters in pixels hold at the resolution they were tuned at (CAD-60's 240 rows)
        and the cost does not grow with the camera's resolution.
    """

    def __post_init__(self) -> None:
        _integers(self)
        self._check_regions()
        self._check_person()
        self._check_floor()
        self._check_mask()


@dataclass(frozen=True)
class ForegroundResult:
    """The person's foreground in one frame.

    Attributes
    ----------
    mask : (H, W) bool, True = person.
    box : (x0, y0, x1, y1) int pixels of the mask's bounding box, x1/y1 exclusive; None when
        nothing was found.
    depth_m : median depth of the person's pixels, metres; NaN when nothing was found.
    found : whether a person region was found.
    reason : why nothing was found ('' when found).
    stability : the MSER stability score of the region the person was found in (its area
        growth over `mser_delta` levels further away, relative; smaller = more stable); NaN
        when nothing was found.
    level : the lowest 8-bit level of the person's pixels (the extremal region's threshold,
        or the far end of the depth part cut from it); -1 if none.
    floor : (4,) float64 plane (nx, ny, nz, d), optical frame, n unit and pointing up, so
        that ``n . p + d`` is the height of point p above the floor (metres); None if no floor
        was found.
    behind : found by `segment_people`'s second look (partly hidden by a nearer person).
    """

    mask: NDArray[np.bool_]
    box: tuple[int, int, int, int] | None = None
    depth_m: float = math.nan
    found: bool = False
    reason: str = REASON_OK
    stability: float = math.nan
    level: int = -1
    floor: NDArray[np.float64] | None = field(default=None, repr=False)
    behind: bool = False

    @property
    def area_px(self) -> int:
        """Number of person pixels."""
        return int(np.count_nonzero(self.mask))


def not_found(shape: tuple[int, ...], reason: str,
              floor: NDArray[np.float64] | None = None) -> ForegroundResult:
    return ForegroundResult(mask=np.zeros(shape, dtype=bool), found=False, reason=reason,
                            floor=floor)
