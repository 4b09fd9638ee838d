"""`tracker`: SLQE Kalman tracking of the detected parts (eqs. 6-16 of the paper).

Several people: one SLQE per track, the detections assigned to tracks each frame, tracks
confirmed after `tracker.confirm_frames` frames and kept `tracker.max_unseen_s` unseen, ids
never reused (`core.people.PeopleTracker`). Frames are tracked in a worker thread: a tracker
slower than its input works on the newest frame and drops the older ones (counted as `dropped`
on /diagnostics; the filters predict through them from the stamps), never queueing them.

Subscriptions
    pose4d/parts/people (pose4d_msgs/SkeletonArray, every person's detected parts), or, from a
    detector that publishes only one person, pose4d/parts (pose4d_msgs/JointArray, the
    detector's 10 or 14 parts, DETECTED or MISSING; subscribed only while nothing publishes
    pose4d/parts/people, `common.PeopleInputs`)
    camera/color/camera_info (sensor_msgs/CameraInfo; the latest, for 3-D positions, read as a
    frame is processed, `polled.LatestIntrinsics`)
    camera/depth/image_raw (sensor_msgs/Image, 16UC1 or 32FC1, registered to colour, moved by
    tracker.depth_shift_px; only when tracker.free_space_m > 0: the image of a frame's
    stamp, `tracker.depth_slop_s`, if it has come, never waited for: an unseen person whose
    place the camera sees through has left, `core.people.free_space`)
Publications (with the input header)
    pose4d/parts/tracked/people (pose4d_msgs/SkeletonArray: every confirmed track's parts,
    DETECTED / TRACKED / MISSING, track_id set; the primary person first; empty: nobody)
    pose4d/parts/tracked (pose4d_msgs/JointArray: the primary person's, all MISSING with
    track_id 0 when nobody is tracked; only while it has a subscriber: the IK reads
    pose4d/parts/tracked/people)
    /diagnostics (also: people, tracks_born, tracks_ended)
Parameters (config/tracker.yaml)
    tracker.kind, tracker.coupling, tracker.process_noise, tracker.measurement_noise_px,
    tracker.gate_chi2, tracker.max_missed_frames, tracker.max_dt_s, tracker.depth_std_m,
    tracker.confirm_frames, tracker.max_unseen_s, tracker.max_hidden_s, tracker.max_held_s,
    tracker.free_space_m, tracker.depth_slop_s, tracker.depth_shift_px, lifecycle.autostart
    (`nodes.lifecycle`: a managed node)
"""

from __future__ import annotations

import math
import time
from typing import Any

from pose4d_msgs.msg import JointArray, SkeletonArray

from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.people import PeopleTracker, TrackingConfig
from pose4d_ros.core.slqe import CvConfig, SlqeConfig
from pose4d_ros.core.stages import TrackerStage
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import (
    PeopleInputs,
    StageMonitor,
    camera_depth,
    pixel_pair,
    run,
)
from pose4d_ros.nodes.lifecycle import AUTOSTART, ManagedNode
from pose4d_ros.nodes.params import Param
from pose4d_ros.nodes.polled import LatestIntrinsics, RecentImages
from pose4d_ros.wire import joints_to_cdr, skeletons_to_cdr, stamp_to_ns

_D = SlqeConfig()
PARAMS = (
    Param('tracker.kind', 'slqe', "'slqe': the paper's skeleton-coupled filter; 'cv': a plain "
          'per-part constant-velocity filter (for comparison).', choices=('slqe', 'cv'),
          restart='another filter would start without the track'),
    Param('tracker.coupling', _D.coupling, "Pull of a part's velocity and acceleration towards "
          "its parent's per 1/30 s (0 = independent parts).", range=(0.0, 0.99), live=True),
    Param('tracker.process_noise', _D.process_noise, 'White jerk spectral density (square '
          'root), px/s^3 per sqrt(Hz) (Q), for a person of 50 px per half metre (a 320x240 '
          "camera 2.85 m away): scaled with the person's size in the image.",
          range=(1e-3, 1e7), live=True),
    Param('tracker.measurement_noise_px', _D.measurement_noise_px, 'Detection standard '
          'deviation per axis at confidence 1, pixels (R), for a person of 50 px per half metre: '
          "scaled with the person's size in the image.", range=(0.01, 1000.0), live=True),
    Param('tracker.gate_chi2', _D.gate_chi2, 'Gate on the squared Mahalanobis innovation '
          '(eq. 16): beyond it a detection is rejected and the prediction used.',
          range=(0.1, 1e9), live=True),
    Param('tracker.max_missed_frames', _D.max_missed_frames, 'Frames without an accepted '
          'detection before a part is dropped (MISSING).', range=(0, 100000), live=True),
    Param('tracker.max_dt_s', _D.max_dt_s, 'A longer gap between stamps restarts the track, '
          'seconds.', range=(0.001, 3600.0), live=True),
    Param('tracker.confirm_frames', TrackingConfig.confirm_frames, 'Frames a new person must '
          'be matched before their track is published, while another track exists.',
          range=(1, 1000), live=True),
    Param('tracker.max_unseen_s', TrackingConfig.max_unseen_s, 'A person unseen this long '
          'ends their track (till then it is predicted), seconds.', range=(0.01, 60.0),
          live=True),
    Param('tracker.max_hidden_s', TrackingConfig.max_hidden_s, 'A person hidden behind a '
          'nearer one ends their track after this long unseen, seconds.', range=(0.01, 60.0),
          live=True),
    Param('tracker.max_held_s', 0.0, 'A person hidden behind another is published at their '
          'last pose this long at most, seconds (then kept unpublished till seen again or '
          'ended); 0: till then.', range=(0.0, 60.0), live=True),
    Param('tracker.free_space_m', TrackingConfig.free_space_m, 'An unseen person ends '
          'their track when the depth image reads this far beyond their predicted torso '
          '(nobody there); 0 = off, no depth subscription.', range=(0.0, 100.0),
          restart='it decides at start-up whether depth is subscribed to'),
    Param('tracker.depth_slop_s', 0.0, 'Largest stamp difference between detected parts and '
          'the camera depth, seconds (0 = exact).', range=(0.0, 1.0),
          restart='the pairing of parts and depth is set up at start-up'),
    Param('tracker.depth_shift_px', [0, 0], "[dx, dy]: the camera's depth image moved by "
          "this many pixels onto its colour image before it is read: the foreground node's "
          '`foreground.depth_shift_px`, given to both (the pipeline node moves it once for '
          'all its stages).', check=pixel_pair, live=True),
    Param('tracker.depth_std_m', TrackerStage.DEPTH_STD_M,
          "Standard deviation of a tracked part's depth in its "
          'covariance, metres.', range=(0.0, 10.0), live=True),
    AUTOSTART,
)


def tracker_settings(p: dict[str, Any]) -> dict[str, Any]:
    """The live settings of the tracker stage (`TrackerStage.configure`) from the parameters
    (also used by the pipeline node)."""
    slqe = SlqeConfig(coupling=p['tracker.coupling'], process_noise=p['tracker.process_noise'],
                      measurement_noise_px=p['tracker.measurement_noise_px'],
                      gate_chi2=p['tracker.gate_chi2'],
                      max_missed_frames=p['tracker.max_missed_frames'],
                      max_dt_s=p['tracker.max_dt_s'])
    # the comparison filter keeps its own tuned noise levels (core.slqe.CvConfig)
    cv = CvConfig(max_missed_frames=p['tracker.max_missed_frames'],
                  max_dt_s=p['tracker.max_dt_s'])
    return {'slqe': slqe, 'cv': cv, 'depth_std_m': p['tracker.depth_std_m']}


def tracker_stage(p: dict[str, Any]) -> TrackerStage:
    """The tracker stage configured by the parameters (also used by the pipeline node)."""
    return TrackerStage(kind=p['tracker.kind'], **tracker_settings(p))


def people_config(p: dict[str, Any]) -> TrackingConfig:
    """How people are told apart (`core.people.TrackingConfig`) from the parameters (the
    pipeline node's include detector.max_people, detector.quiet_frames and
    detector.keep_unseen_s)."""
    return TrackingConfig(max_people=p.get('detector.max_people', TrackingConfig.max_people),
                          quiet_frames=p.get('detector.quiet_frames', TrackingConfig.quiet_frames),
                          detector_keep_s=p.get('detector.keep_unseen_s',
                                                TrackingConfig.detector_keep_s),
                          confirm_frames=p['tracker.confirm_frames'],
                          max_unseen_s=p['tracker.max_unseen_s'],
                          max_hidden_s=p['tracker.max_hidden_s'],
                          max_held_s=p['tracker.max_held_s'] or math.inf,
                          free_space_m=p['tracker.free_space_m'])


class TrackerNode(ManagedNode):
    """Tracks the parts of every person; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('tracker', PARAMS, check=tracker_settings)

    def configure(self, p: dict[str, Any]) -> None:
        self.template = tracker_stage(p)
        self.people = PeopleTracker(self.template, people_config(p))
        self.people.warm_up(cad60_intrinsics())
        self.monitor = StageMonitor(self, 'tracker')
        self.monitor.values.update(people=0, tracks_born=0, tracks_ended=0)
        self.pub_people = self.create_publisher(SkeletonArray, 'pose4d/parts/tracked/people',
                                                qos.OUTPUT_QOS)
        self.pub = self.create_publisher(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)

    def activate(self, p: dict[str, Any]) -> None:
        self.camera = LatestIntrinsics(self, self.monitor)
        self.depth_shift = p['tracker.depth_shift_px']
        self.depth = (RecentImages(self, self.monitor, 'camera/depth/image_raw',
                                   lambda msg: camera_depth(msg, self.depth_shift),
                                   slop_ns=int(p['tracker.depth_slop_s'] * 1e9))
                      if p['tracker.free_space_m'] > 0 else None)
        self.inputs = PeopleInputs(self, 'pose4d/parts/people', 'pose4d/parts', [],
                                   self.process, self.monitor)
        self.get_logger().info(
            f'tracking {self.resolve_topic_name("pose4d/parts/people")} (or '
            f'{self.resolve_topic_name("pose4d/parts")}) -> '
            f'{self.resolve_topic_name("pose4d/parts/tracked")}(/people) with '
            f'{self.template.kind}')

    def process(self, detections: list[JointSet], header: Any, _: tuple) -> None:
        if (p := self.params.changes()) is not None:
            self.people.configure(**tracker_settings(p))
            self.people.config = people_config(p)
            self.depth_shift = p['tracker.depth_shift_px']
        t0 = time.perf_counter()
        stamp = stamp_to_ns(header.stamp)
        if self.monitor.time_jumped(stamp):
            self.people.reset()
        intrinsics = self.camera.latest()
        try:
            # read only when a track goes unseen, or a detection under the birth score may
            # be of a person cut by the image's bottom edge
            depth = ((lambda: self.depth.at(stamp))
                     if self.depth is not None and intrinsics is not None else None)
            tracked = self.people.step(detections, stamp * 1e-9, intrinsics, depth)
        except ValueError as exc:
            self.monitor.bad_input(f'pose4d/parts frame at {stamp} ns refused: {exc}')
            return
        values = self.monitor.values
        values['people'] = len(tracked)
        values['tracks_born'] += len(self.people.born)
        values['tracks_ended'] += len(self.people.ended)
        self.pub_people.publish(skeletons_to_cdr(tracked, header))
        if self.pub.get_subscription_count():  # the primary person alone: on demand
            primary = tracked[0] if tracked else JointSet.missing(
                detections[0].names if detections else self.template.tree.names)
            self.pub.publish(joints_to_cdr(primary, header))
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(TrackerNode, args)
