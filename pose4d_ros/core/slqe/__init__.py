"""SLQE: a skeleton-constrained Kalman filter for the parts of a tracked person.

After Martinez Berti, Sanchez Salmeron and Ricolfe Viala, "4-Dimensional deformation part model
for pose estimation using Kalman filter constraints", eqs. (6)-(16). Everything is in the colour
image, pixels (u, v), as in the paper.

Model
-----
Each part i has the state ``s_i = (x, y, vx, vy, ax, ay)`` (pixels, px/s, px/s^2; eq. 6) and the
whole pose is ``s = (s_0, ..., s_{P-1})``. With ``dt`` the time between two frames (taken from
the stamps, so irregular frame rates are handled), the prediction is (eqs. 7-9)::

    s' = A(dt) s,    Sigma' = A Sigma A^T + Q(dt)

``A`` couples connected parts (eqs. 10-12). The paper writes it for 8 joints as blocks ``A1`` (a
part's own constant-acceleration kinematics) and ``A2`` (the pull of the connected part); here it
is built from any part tree (`core.skeleton.PARTS_10` by default): a child's velocity and
acceleration are blended with its parent's before they are integrated,

    d_c <- (1 - k) d_c + k d_p          (d = velocity and acceleration)
    A_cc = F(dt) diag(1, 1 - k, 1 - k) (x) I2,      A_cp = F(dt) diag(0, k, k) (x) I2,

with ``F(dt)`` the kinematic transition of one axis (``A1`` of the paper) and ``k``
the coupling (`SlqeConfig.coupling` per 1/30 s, rescaled for other ``dt`` so that the pull per
second does not depend on the frame rate). ``k = 0`` gives independent parts. The root (neck)
has ``A_rr = F``. An occluded wrist thus keeps moving with its shoulder rather than flying off
along its last velocity.

One change to ``A1``: the acceleration decays with a time constant (`accel_time_s`, Singer's
manoeuvre model, integrated exactly into velocity and position) instead of persisting, because
a waving hand's acceleration turns within a fifth of a second: kept, it carries a part whose
detections are rejected far past the point where it turned.

``Q(dt)`` is the discretised white noise of the highest derivative (jerk for constant
acceleration, acceleration for constant velocity) with spectral density
``process_noise**2``. The measurement (eq. 13) is ``z_i = H s_i + r_i``, ``H`` picking the
positions, ``R_i = measurement_noise_px**2 / confidence_i * I2``. The update is the Kalman update
(eqs. 14-15), Joseph form.

The choice of eq. (16) between the filter's estimate and the detection is made per part from the
innovation ``y_i = z_i - H s'_i`` and its covariance ``S_i``:

- ``y_i^T S_i^-1 y_i <= gate_chi2``: the detection agrees with the prediction; it is used for the
  update and the part is DETECTED (its output is the filtered estimate, or the detection itself
  with ``output='detection'``, the literal reading of eq. 16).
- beyond the gate: an outlier; the detection is rejected and the prediction is used (TRACKED),
  unless it is within the gate of where the part was at the previous frame: a hand that stops or
  turns back, which the prediction overshoots, is restarted on its detection
  (`stop_hypothesis`).
- a limb that turns fast about its joint (a hand whipped round the elbow) outruns the
  prediction for frames on end, while the detections of it stay where the limb is: so an arm's
  detection beyond the gate, its previous one rejected too, is restarted on (DETECTED) when its
  parent's detection is accepted and the limb between them keeps its length, within
  `limb_tolerance` of the tracked one.
- when ``drift_frames`` consecutive detections are rejected but agree with each other (each within
  ``drift_radius_px`` per 1/30 s of the previous one), the filter is the one that drifted: the
  part is re-initialised on the detection (DETECTED).
- a restart may follow a detector stuck on a wrong place for a few frames; so the track from
  before it is kept, predicted, for `shadow_frames`, and a detection beyond the gate but within
  that track's brings it back (DETECTED).

Pixels depend on the person's distance and the camera's resolution: a hand moves twice as many
pixels per second at 1.5 m as at 3 m, or at 640x480 as at 320x240. So the parameters in pixels
(`process_noise`, `measurement_noise_px`, `drift_radius_px`, `init_velocity_std`,
`init_accel_std`) are stated for a person of `REFERENCE_SCALE_PX` pixels per half a metre of
body (a 320x240 Kinect 2.85 m away), and each step may be given the person's scale in its frame
(``step(..., scale_px=...)``), which multiplies them all by ``scale_px / REFERENCE_SCALE_PX``
(Q by its square): the same filter, in units of the person.

Parts without a detection (NaN) are predicted only (TRACKED). A part that has had no accepted
detection for more than ``max_missed_frames`` is dropped (MISSING, NaN) and re-initialised when
detected again; a time gap over ``max_dt_s``, a stamp going backwards or `reset` restart the
whole track.

Design: `SlqeConfig` (frozen) + `TrackState` (frozen arrays) + the pure functions `predict`,
`update` and `output`; `SlqeTracker` wraps them behind one per-frame call,
``tracker.step(uv, confidence, stamp_s)``. `ConstantVelocityTracker` is the plain per-part
constant-velocity Kalman filter used for comparison, with the same interface.

The package, one module a job: `config` (the parameters, the state and what a step returns),
`motion` (A and Q, the prediction), `update` (the gate, the Kalman update and the restart
hypotheses; the output), `tracker` (the per-frame trackers), `kernel` (one step compiled).

The filter is written twice, on purpose: the Python functions above are its readable statement
(the paper's equations, what the behaviour tests read), and `kernel.slqe_step` does exactly
their work as one compiled call (the Python path costs some 130 interpreter calls per person
and frame). A change to the filter is made in both, in the same order and arithmetic: first in
the Python functions (with a behaviour test in `test/test_slqe.py`), then in the kernel (a new
setting also goes into `kernel.config_params`); `test_compiled_step_is_the_python_functions`
runs both over the same noisy, gapped detections and fails until they agree in every array and
counter, and a new setting's non-default value belongs in its parameter list.
"""

from pose4d_ros.core.slqe.config import (
    NOMINAL_DT_S,
    REFERENCE_SCALE_PX,
    SlqeConfig,
    Source,
    TrackOutput,
    TrackState,
    UpdateInfo,
    initial_state,
)
from pose4d_ros.core.slqe.motion import (
    axis_process_noise,
    axis_transition,
    coupling_at,
    predict,
    process_noise_matrix,
    transition_matrix,
)
from pose4d_ros.core.slqe.tracker import ConstantVelocityTracker, CvConfig, SlqeTracker
from pose4d_ros.core.slqe.update import MIN_WEIGHT, output, update

__all__ = [
    'MIN_WEIGHT', 'NOMINAL_DT_S', 'REFERENCE_SCALE_PX', 'ConstantVelocityTracker', 'CvConfig',
    'SlqeConfig', 'SlqeTracker', 'Source', 'TrackOutput', 'TrackState', 'UpdateInfo',
    'axis_process_noise', 'axis_transition', 'coupling_at', 'initial_state', 'output',
    'predict', 'process_noise_matrix', 'transition_matrix', 'update',
]
