"""`tracker`: SLQE Kalman tracking of the detected parts (eqs. 6-16 of the paper).

Subscriptions
    pose4d/parts (pose4d_msgs/JointArray, the detector's 10 or 14 parts, DETECTED or MISSING)
    camera/color/camera_info (sensor_msgs/CameraInfo; the latest, for 3-D positions)
Publications
    pose4d/parts/tracked (pose4d_msgs/JointArray, the same parts: DETECTED / TRACKED / MISSING,
    with the input header), /diagnostics
Parameters (config/tracker.yaml)
    tracker.kind, tracker.coupling, tracker.process_noise, tracker.measurement_noise_px,
    tracker.gate_chi2, tracker.max_missed_frames, tracker.max_dt_s, tracker.depth_std_m
"""

from __future__ import annotations

import time
from typing import Any

from pose4d_msgs.msg import JointArray
from rclpy.node import Node

from pose4d_ros.core.pipeline import TrackerStage
from pose4d_ros.core.slqe import CvConfig, SlqeConfig
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import LatestIntrinsics, StageMonitor, run, subscribe
from pose4d_ros.nodes.convert import (
    joints_from_msg,
    joints_to_cdr,
    stamp_to_ns,
)
from pose4d_ros.nodes.params import NodeParams, Param

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
    Param('tracker.depth_std_m', TrackerStage.DEPTH_STD_M,
          "Standard deviation of a tracked part's depth in its "
          'covariance, metres.', range=(0.0, 10.0), live=True),
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


class TrackerNode(Node):
    """Tracks the parts of one person; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('tracker')
        self.params = NodeParams(self, PARAMS, check=tracker_settings)
        self.stage = tracker_stage(self.params.values)
        self.monitor = StageMonitor(self, 'tracker')
        self.camera = LatestIntrinsics(self, self.monitor)
        self.pub = self.create_publisher(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
        subscribe(self, JointArray, 'pose4d/parts', self.on_parts, qos.INPUT_QOS, self.monitor)
        self.get_logger().info(
            f'tracking {self.resolve_topic_name("pose4d/parts")} -> '
            f'{self.resolve_topic_name("pose4d/parts/tracked")} with {self.stage.kind}')

    def on_parts(self, msg: JointArray) -> None:
        if (p := self.params.changes()) is not None:
            self.stage.configure(**tracker_settings(p))
        t0 = time.perf_counter()
        stamp = stamp_to_ns(msg.header.stamp)
        if self.monitor.time_jumped(stamp):
            self.stage.reset()
        try:
            parts = joints_from_msg(msg)
            tracked = self.stage.step(parts, stamp * 1e-9, self.camera.intrinsics)
        except ValueError as exc:
            self.monitor.bad_input(f'pose4d/parts frame at {stamp} ns refused: {exc}')
            return
        self.pub.publish(joints_to_cdr(tracked, msg.header))
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(TrackerNode, args)
