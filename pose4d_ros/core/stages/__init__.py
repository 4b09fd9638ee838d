"""The stages of the tracker as objects with one per-frame call, shared by nodes and tools.

The ROS nodes (`foreground`, `detector`, `tracker`, `ik`) and the offline tools call these same
objects (composed in `core.pipeline`), so an offline evaluation and a live run of the graph give
the same answers on the same frames. One module a stage (`stages.foreground`, `stages.detector`,
`stages.tracker`, `stages.ik`; what they share, a JointSet checked and put in a stage's order,
in `stages._shared`); import them from here.

- `ForegroundStage`: the person's mask from the depth image (`core.foreground`: floor removal
  and MSER), applied to colour and depth.
- `DetectorStage`: the 4D deformable part model (`core.dpm`) on the masked frame; each part's
  pixel is lifted to 3-D with the robust depth of the person's pixels around it, plus the
  model's learned depth offset from the visible surface to the joint centre.
- `TrackerStage`: the SLQE Kalman filter (`core.slqe`, eqs. 6-16) on the detected parts' pixels,
  plus each part's depth carried from its last detection, so tracked parts have a 3-D position
  too (back-projected with the camera's intrinsics).
- `IkStage`: inverse kinematics (`core.kinematics`, or the paper's Denavit-Hartenberg chains,
  `core.dh`, eqs. 17-24) completing elbows and knees from shoulders/hips and wrists/ankles in
  3-D, the swivel chosen by the depth image; output the 14-joint skeleton
  (`skeleton.SKELETON_14`).
"""

from pose4d_ros.core.stages._shared import check_known, reorder, reordered_arrays
from pose4d_ros.core.stages.detector import PRIOR_MAX_GAP_S, DetectorStage
from pose4d_ros.core.stages.foreground import ForegroundStage
from pose4d_ros.core.stages.ik import IkStage
from pose4d_ros.core.stages.tracker import TrackerStage

__all__ = [
    'PRIOR_MAX_GAP_S',
    'DetectorStage',
    'ForegroundStage',
    'IkStage',
    'TrackerStage',
    'check_known',
    'reorder',
    'reordered_arrays',
]
