"""Person foreground from the depth image: floor removal and MSER (first stage of the paper).

After Martinez Berti, Sanchez Salmeron and Ricolfe Viala, "4-Dimensional deformation part model
for pose estimation using Kalman filter constraints", section 3 (foreground extraction): maximally
stable extremal regions (MSER, Matas et al. 2002) are found on the depth image, regions larger
than a trained area threshold are background (walls, floor), and the person's region masks the
colour and depth images before the part detector runs. The paper gives no more detail; the rest
of this package is our design, measured on the synthetic CAD-60-format sets.

Steps of `segment` (one depth frame, float32 metres, NaN = no reading):

1. Floor plane. RANSAC on the 3-D points of the lower part of the image: planes through three
   points whose normal is within `floor_max_tilt_deg` of the optical "up" (-y) and that pass
   `floor_min_height_m`-`floor_max_height_m` below the camera; the plane with most inliers
   (tolerance growing with z^2, as Kinect noise does) is refined by weighted least squares.
   Pixels less than `floor_tolerance_m` above it are dropped. Without this, the floor in front
   of the person is nearer than the person and joins the feet at every depth threshold, so
   the person's region leaks into the floor (no person-sized region is left at all).
2. 8-bit depth. Depth in [`depth_near_m`, `depth_far_m`] maps linearly to 255..1 (near is
   bright); no reading, floor and out-of-range pixels are 0. A connected component of
   ``{g >= t}`` (an extremal region) is a set of connected pixels nearer than level t.
3. Extremal regions and their stability. The component tree of all levels is built by
   union-find (numba, on every `tree_step`-th pixel). A region R(t)'s stability score is
   ``(|R(t - delta)| - |R(t)|) / |R(t)|``, its growth when the threshold moves `mser_delta`
   levels (``delta * (far - near) / 254`` metres) further away; regions with a score above
   `mser_max_variation` or larger than `max_region_area_px` (the trained background area
   threshold) are dropped. This is MSER's criterion, but not OpenCV's MSER: OpenCV keeps a
   region only when it is more stable than its parent, and the parent of a free-standing
   person (the person merged with the wall behind) is usually more stable, so OpenCV never
   reports the whole person.
4. Person rules, in two stages. Stage 1 uses the tree's statistics (box, mean depth) and
   examines the best `max_candidates` regions (score ``log(area) - stability_weight *
   variation - border_penalty * touches_side``; regions within the person bounds first).
   Stage 2 traces each at full resolution (flood fill), splits it at empty depth gaps wider
   than `occluder_gap_m` (an occluder in front, furniture behind) and, when a part is deeper
   than `person_max_extent_m`, also at Otsu's threshold of its depth histogram (a table whose
   top recedes towards the person). Every part must pass the person-size rules: box height
   ``h_px z / fy`` and width ``w_px z / fx`` at its median depth z, surface
   ``n_px z^2 / (fx fy)``, fill of its box, depth extent, and, with a floor, the height above
   the floor of its top rows (head or hands) and bottom rows (feet or the occluder's top).
   The best-scoring part wins; with `previous`, a part overlapping the previous box gets
   `previous_bonus`. A person nearer than the camera sees whole (1.2 m away, head to thighs) is
   cut by the image's bottom edge and shorter than a whole person may be: parts cut by that edge
   get smaller lower bounds on height and surface and no rule on their bottom rows
   (`person_min_cut_height_m`): in `segment`, when no part passes the rules; in
   `segment_people`, beside those that do. The best few such regions are examined besides the
   best few others, never in their place. The image's edges are where the depth readings end
   (`person.seen_edges`): a depth image registered to the colour camera has a band without
   readings along its borders, and a person cut by the image stops there. A person of the
   previous frame who bends or crouches (a pick-up, a bow) shrinks under a whole person's
   bounds, to a table's size: a part that overlaps their previous box (`FOLLOW_OVERLAP`) with
   its top near that box's top (`FOLLOW_TOP`: one bends over several frames) passes with a cut
   person's lower bounds and its top at least `person_min_bent_top_m` above the floor, when no
   part passing the usual rules overlaps that box (`bent_rules`).
5. Completion. No-reading pixels that a small closing of the mask adds (Kinect loses the
   readings in a ragged band along depth edges) join the mask; optionally, holes of no-reading
   pixels are filled.

Defaults were tuned on the synthetic training set only (UTKinect subjects s01-s06 rendered in
random rooms by `pose4d synth`, 1536 frames): a coordinate search over the parameters
maximising the mean mask IoU against the rendered person masks, the person rules searched on
the stored candidate parts of every frame. The test set (s07-s08, unseen bodies and rooms) was
used only to report. The tuning script is kept with the project notes
(``foreground_tune.py``); its results are in `ForegroundConfig`'s docstring.

The package, one module a job: `floor` (step 1), `regions` (steps 2 and 3), `person` (step 4),
`mask` (step 5, the working resolution, holding and applying the mask); `config` holds their
parameters, one dataclass each, joined in `ForegroundConfig`; `segmentation` composes them.
"""

from pose4d_ros.core.foreground.config import (
    REASON_NO_DEPTH,
    REASON_NO_PERSON,
    REASON_NO_REGION,
    REASON_OK,
    REASON_TOO_SMALL,
    FloorConfig,
    ForegroundConfig,
    ForegroundResult,
    MaskConfig,
    PersonConfig,
    RegionConfig,
)
from pose4d_ros.core.foreground.floor import fit_floor, floor_height
from pose4d_ros.core.foreground.mask import apply_mask, hold
from pose4d_ros.core.foreground.person import Part, part_score, person_rules, size_rules
from pose4d_ros.core.foreground.regions import depth_to_levels
from pose4d_ros.core.foreground.segmentation import segment, segment_people

__all__ = [
    'REASON_NO_DEPTH', 'REASON_NO_PERSON', 'REASON_NO_REGION', 'REASON_OK', 'REASON_TOO_SMALL',
    'FloorConfig', 'ForegroundConfig', 'ForegroundResult', 'MaskConfig', 'Part', 'PersonConfig',
    'RegionConfig', 'apply_mask', 'depth_to_levels', 'fit_floor', 'floor_height', 'hold',
    'part_score', 'person_rules', 'segment', 'segment_people', 'size_rules',
]
