"""`detector`: 4D deformable part model (HOG on colour and depth) on the masked frame.

Finds the person's parts with the trained mixture-of-parts model, searching only the
foreground's box at the scale its depth gives (times the person's own scale factor, chosen per
track: `core.dpm.scale`), and lifts each part to 3-D with a robust depth look-up. Inputs are
paired by stamp and processed in order; a detector slower than the camera works on the newest
frame and drops the others (counted) instead of falling behind.

Subscriptions
    pose4d/foreground/color (sensor_msgs/Image, rgb8/bgr8)
    pose4d/foreground/depth (sensor_msgs/Image, 16UC1 mm or 32FC1 m)
    pose4d/foreground/mask (sensor_msgs/Image, mono8, 255 = person)
    camera/color/camera_info (sensor_msgs/CameraInfo; the latest)
Publications
    pose4d/parts (pose4d_msgs/JointArray: parts DETECTED or MISSING, input header), /diagnostics
Parameters (config/detector.yaml)
    detector.model, detector.n_levels, detector.margin, detector.person_scales,
    detector.scale_warm_up_frames, detector.scale_probe_every, detector.min_confidence
    (a part's depth look-up is the model's: `core.lifting.lift_parts`)
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from pose4d_msgs.msg import JointArray
from rclpy.node import Node
from sensor_msgs.msg import Image

from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.dpm.infer import SearchConfig
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.dpm.scale import ScaleConfig
from pose4d_ros.core.pipeline import DetectorStage
from pose4d_ros.models import model_path
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import LatestIntrinsics, PairedInputs, StageMonitor, run
from pose4d_ros.nodes.convert import (
    color_from_msg,
    depth_from_msg,
    image_to_array,
    joints_to_cdr,
    stamp_to_ns,
)
from pose4d_ros.nodes.params import NodeParams, Param, ParameterError

_S = SearchConfig()
_C = ScaleConfig()


def _model_exists(value: str) -> str | None:
    try:
        model_path(value)
    except FileNotFoundError as exc:
        return str(exc)
    return None


def _scale_factors(value: list[float]) -> str | None:
    try:
        ScaleConfig(factors=tuple(value))
    except ValueError as exc:
        return str(exc)
    return None


PARAMS = (
    Param('detector.model', 'rgbd_14', 'Part model: the name of a shipped model (rgbd_14, '
          'rgbd_10, rgb_10, ...) or the path of a .npz.', check=_model_exists,
          restart='the model is loaded, and its kernels compiled, at start-up'),
    Param('detector.n_levels', _S.n_levels, 'Pyramid levels searched around the scale the '
          "person's depth predicts.", range=(1, 9), live=True),
    Param('detector.margin', _S.margin, 'Search margin around the foreground box, in person '
          'scales.', range=(0.0, 5.0), live=True),
    Param('detector.person_scales', list(_C.factors), "Factors on the person scale that depth "
          "predicts, for people larger or smaller than the model's training bodies: each is "
          'searched in the first frames of a track and the best-scoring one kept (then one level '
          'a frame); [1.0] searches only the predicted scale.', check=_scale_factors, live=True),
    Param('detector.scale_warm_up_frames', _C.warm_up_frames, 'Frames at the start of a track '
          'in which every person scale is searched.', range=(1, 1000), live=True),
    Param('detector.scale_probe_every', _C.probe_every, 'After the warm-up, a neighbouring '
          'person scale is also searched every this many frames (0 = never).',
          range=(0, 100000), live=True),
    Param('detector.min_confidence', DetectorStage.MIN_CONFIDENCE,
          'Parts less confident than this are MISSING.',
          range=(0.0, 1.0), live=True),
    Param('detector.arm_prior', _S.arm_prior, "Weight of the previous frame's elbows and "
          'wrists (at most 0.25 s old) when each arm is chosen among the few best the part model '
          'allows, per squared person scale of distance; 0 = the part model alone.',
          range=(0.0, 100.0), live=True),
)


def detector_settings(p: dict[str, Any]) -> dict[str, Any]:
    """The live settings of the detector stage (`DetectorStage.configure`) from the
    parameters (also used by the pipeline node)."""
    return {'search': SearchConfig(n_levels=p['detector.n_levels'], margin=p['detector.margin'],
                                   arm_prior=p['detector.arm_prior']),
            'scale': ScaleConfig(factors=tuple(p['detector.person_scales']),
                                 warm_up_frames=p['detector.scale_warm_up_frames'],
                                 probe_every=p['detector.scale_probe_every']),
            'min_confidence': p['detector.min_confidence']}


def detector_stage(p: dict[str, Any]) -> DetectorStage:
    """The detector stage configured by the parameters (also used by the pipeline node)."""
    path = model_path(p['detector.model'])
    try:
        model = load_model(path)
    except (OSError, ValueError) as exc:
        raise ParameterError(f'parameter detector.model: {exc}') from None
    return DetectorStage(model, **detector_settings(p))


class DetectorNode(Node):
    """Detects the person's parts; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('detector')
        self.params = NodeParams(self, PARAMS, check=detector_settings)
        p = self.params.values
        self.stage = detector_stage(p)
        self.stage.warm_up(cad60_intrinsics())  # compile before the first camera frame
        self.monitor = StageMonitor(self, 'detector')
        self.camera = LatestIntrinsics(self, self.monitor)
        self.pub = self.create_publisher(JointArray, 'pose4d/parts', qos.OUTPUT_QOS)
        self.inputs = PairedInputs(
            self, [(Image, f'pose4d/foreground/{name}', qos.SENSOR_QOS)
                   for name in ('color', 'depth', 'mask')], self.process, self.monitor)
        self.get_logger().info(
            f'detecting {len(self.stage.names)} parts with {Path(str(p["detector.model"])).name}'
            f' ({self.stage.model.channels}) in {self.resolve_topic_name("pose4d/foreground")}'
            f' -> {self.resolve_topic_name("pose4d/parts")}')

    def process(self, items: Any) -> None:
        if (p := self.params.changes()) is not None:
            self.stage.configure(**detector_settings(p))
        color_msg, depth_msg, mask_msg = items
        t0 = time.perf_counter()
        stamp = stamp_to_ns(color_msg.header.stamp)
        if self.monitor.time_jumped(stamp):
            self.stage.reset()
        try:
            color = color_from_msg(color_msg)
            depth = depth_from_msg(depth_msg)
            mask = image_to_array(mask_msg) > 127
            if not color.shape[:2] == depth.shape == mask.shape:
                raise ValueError(f'colour {color.shape[:2]}, depth {depth.shape} and mask '
                                 f'{mask.shape} differ in size')
            parts = self.stage.step(color, depth, self.camera.intrinsics, mask=mask,
                                    stamp_s=stamp * 1e-9)
        except ValueError as exc:
            self.monitor.bad_input(f'frame at {stamp} ns refused: {exc}')
            return
        if self.stage.last_flags:
            self.get_logger().debug(f'frame at {stamp} ns: {", ".join(self.stage.last_flags)}')
        self.pub.publish(joints_to_cdr(parts, color_msg.header))
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(DetectorNode, args)
