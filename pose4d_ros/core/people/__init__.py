"""Several people at once: one detector state, one SLQE and one IK per person, with stable ids.

The paper's stages extend to several people as they are: the foreground gives one candidate
per person (`core.foreground.segment_people`), the part model searches each candidate
(`PeopleDetector`), each person's parts are tracked by their own SLQE (`PeopleTracker`) and
completed by their own IK with their own learned bone lengths (`PeopleIk`).

Association (our design; the paper tracks one person). Each frame, detections are assigned to
the confirmed tracks by one global assignment (`scipy.optimize.linear_sum_assignment`), then
the detections left to the tentative tracks (`confirmed_first`), on the squared
Mahalanobis distance between torso points in 3-D: the track's torso predicted to this frame at
its velocity, its covariance the SLQE's covariance of the torso joints plus the detection's,
plus `TrackingConfig.torso_std_m` and a spread growing with the time the track went unseen
(`max_speed_mps`). A pair beyond `gate_chi2` is never assigned, and takes no part in the
assignment (`assign`). A detection left over starts a
tentative track, confirmed (and given its id) after `confirm_frames` frames matched, or at
once while no track is confirmed: every detection the part model scores at least
`trust_score`, or else the foreground's best region (trusted as the single-person tracker
always trusted its one detection). A confirmed track survives `max_unseen_s` unseen (its
parts predicted, TRACKED, as long as the SLQE keeps them), or `max_hidden_s` while held behind
a nearer person, and is matched again when the person comes back, and every track ends at
a gap in the stream (`max_gap_s`); ids count up from 1 in a run and are never reused. One
track and one detection are always paired: the SLQE's own gate then judges each part, as it
does for a single person, except the joints a nearer person's body covers in the image, whose
last estimates are kept (`hold_occluded`).

The primary person (the one `/pose4d/skeleton` carries): of the confirmed tracks seen this
frame, the longest tracked (matched in most frames; the first confirmed on a tie); when none is
seen, the longest-tracked one still predicted. Outputs are ordered primary first, then by id.

The same detector slots do the same for candidates before detection (`PeopleDetector`): each
slot keeps one person's detector state (their scale, the previous frame's parts that guide
the arms), matched to candidates by the 3-D centre of their regions.

The package, one module a job: `config` (`TrackingConfig`, the parameters), `assignment` (the
torso points and the gated assignment on their Mahalanobis distances), `detector`
(`PeopleDetector`, the detector slots), `tracker` (`PeopleTracker`, the tracks and their ids;
`free_space`), `ik` (`PeopleIk`), `labels` (the label image of a frame's people, between the
foreground and the detector).
"""

from pose4d_ros.core.people.assignment import TORSO, assign, torso, torso_px
from pose4d_ros.core.people.config import TrackingConfig
from pose4d_ros.core.people.detector import STILL_IOU, STILL_M, PeopleDetector
from pose4d_ros.core.people.ik import PeopleIk
from pose4d_ros.core.people.labels import people_from_labels, people_labels
from pose4d_ros.core.people.tracker import PeopleTracker, free_space

__all__ = [
    'STILL_IOU', 'STILL_M', 'TORSO', 'PeopleDetector', 'PeopleIk', 'PeopleTracker',
    'TrackingConfig', 'assign', 'free_space', 'people_from_labels', 'people_labels', 'torso',
    'torso_px',
]
