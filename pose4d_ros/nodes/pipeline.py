"""`pipeline`: every stage in one process, one executor, for the lowest latency.

The same stages as the `foreground`, `detector`, `tracker` and `ik` nodes (the same core
objects, the same parameters), called one after the other in one callback per frame, without
the serialisation and transport of images between processes. Colour, depth and camera_info are
paired by stamp and processed in order; a pipeline slower than the camera works on the
newest frames (at most two waiting, `common.STAGE_QUEUE`) and drops the others (counted).

Subscriptions
    camera/color/image_raw, camera/depth/image_raw (sensor_msgs/Image),
    camera/color/camera_info (sensor_msgs/CameraInfo)
Several people as the per-stage graph tracks them (`FramePipeline(people=...)`): every person
region searched (at most detector.max_people), one SLQE and one IK per track.

Publications (all with the colour image's header)
    pose4d/skeletons (pose4d_msgs/SkeletonArray, everyone), pose4d/skeleton (pose4d_msgs/
    JointArray, 14 joints, the primary person), pose4d/skeleton/markers, /tf (the joints, as
    the ik node publishes them), humans/bodies/... (the REP 155 bodies, as the ik node does),
    pose4d/parts, pose4d/parts/tracked (JointArray, the model's parts; while subscribed),
    pose4d/foreground/{mask,color,depth} (if pipeline.publish_foreground; while subscribed),
    /diagnostics
Parameters (config/pipeline.yaml)
    those of the foreground, detector, tracker and ik nodes, pipeline.publish_foreground and
    lifecycle.autostart (`nodes.lifecycle`: a managed node)
"""

from __future__ import annotations

import time
from typing import Any

from pose4d_msgs.msg import JointArray
from sensor_msgs.msg import Image

from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.people import people_labels
from pose4d_ros.core.pipeline import FramePipeline
from pose4d_ros.nodes import detector, foreground, ik, qos, tracker
from pose4d_ros.nodes.common import PairedInputs, StageMonitor, camera_depth, run
from pose4d_ros.nodes.lifecycle import AUTOSTART, ManagedNode
from pose4d_ros.nodes.params import Param
from pose4d_ros.wire import (
    color_from_msg,
    intrinsics_from_msg,
    joints_to_cdr,
    stamp_to_ns,
)

# a stage node's own reading of a camera topic the pipeline reads once for all its stages
_NOT_HERE = ('tracker.depth_shift_px',)  # the pipeline's: foreground.depth_shift_px

PARAMS = (
    *(p for stage in (foreground, detector, tracker, ik) for p in stage.PARAMS
      if p is not AUTOSTART and p.name not in _NOT_HERE),
    Param('pipeline.publish_foreground', True, 'Also publish the foreground mask and the '
          'masked colour and depth images.',
          restart='it decides at start-up whether the foreground images have publishers'),
    AUTOSTART,
)


def _settings(p: dict[str, Any]) -> tuple:
    """Every stage's live settings (ValueError for values that break a stage's rules)."""
    return (foreground.foreground_settings(p), detector.detector_settings(p),
            tracker.tracker_settings(p), ik.ik_settings(p))


class PipelineNode(ManagedNode):
    """All stages on each RGB-D frame; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('pipeline', PARAMS, check=_settings)

    def configure(self, p: dict[str, Any]) -> None:
        self.pipeline = FramePipeline(
            detector.detector_stage(p), foreground=foreground.foreground_stage(p),
            tracker=tracker.tracker_stage(p), ik=ik.ik_stage(p),
            people=tracker.people_config(p))
        self.pipeline.warm_up(cad60_intrinsics())  # compile before the first camera frame
        self.publish_foreground = p['pipeline.publish_foreground']
        self.depth_shift = p['foreground.depth_shift_px']
        self.monitor = StageMonitor(self, 'pipeline')
        self.monitor.values.update(people=0, people_over_limit=0, tracks_born=0,
                                   tracks_ended=0)
        self.outputs = ik.SkeletonOutputs(self, p)
        pub = self.create_publisher
        self.pubs = {
            'parts': pub(JointArray, 'pose4d/parts', qos.OUTPUT_QOS),
            'tracked': pub(JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS),
        }
        if self.publish_foreground:
            for name in ('mask', 'color', 'depth'):
                self.pubs[name] = pub(Image, f'pose4d/foreground/{name}', qos.OUTPUT_QOS)

    def activate(self, p: dict[str, Any]) -> None:
        self.inputs = PairedInputs(self, foreground.CAMERA_TOPICS, self.process, self.monitor,
                                   slop_ns=int(p['foreground.slop_s'] * 1e9))
        self.get_logger().info(
            f'pipeline on {self.resolve_topic_name("camera/color/image_raw")} -> '
            f'{self.resolve_topic_name("pose4d/skeleton")} (model {p["detector.model"]}, '
            f'tracker {p["tracker.kind"]}, IK {p["ik.method"]}, depth {p["ik.use_depth"]})')

    def reconfigure(self, p: dict[str, Any]) -> None:
        """The live parameters' new values, between two frames."""
        self.pipeline.configure(foreground=foreground.foreground_settings(p),
                                detector=detector.detector_settings(p),
                                tracker=tracker.tracker_settings(p), ik=ik.ik_settings(p),
                                people=tracker.people_config(p))
        self.outputs.configure(p)

    def process(self, items: Any) -> None:
        if (p := self.params.changes()) is not None:
            self.reconfigure(p)
            self.depth_shift = p['foreground.depth_shift_px']
        color_msg, depth_msg, info_msg = items
        t0 = time.perf_counter()
        stamp = stamp_to_ns(color_msg.header.stamp)
        try:
            intrinsics = intrinsics_from_msg(info_msg)
            out = self.pipeline.step(color_from_msg(color_msg),
                                     camera_depth(depth_msg, self.depth_shift),
                                     intrinsics, stamp * 1e-9)
        except ValueError as exc:
            self.monitor.bad_input(f'frame at {stamp} ns refused: {exc}')
            return
        if out.jump_s is not None:  # the pipeline checks the stamps and starts anew itself
            self.monitor.jumped(out.jump_s)
        header = color_msg.header
        values = self.monitor.values
        values['people'] = len(out.people)
        values['people_over_limit'] += max(out.candidates - len(out.foregrounds), 0)
        values['tracks_born'] += len(out.born)
        values['tracks_ended'] += len(out.ended)
        self.outputs.publish(list(out.people), header, intrinsics)
        for name, joints in (('parts', out.parts), ('tracked', out.tracked)):
            if self.pubs[name].get_subscription_count():  # intermediate results: on demand
                self.pubs[name].publish(joints_to_cdr(joints, header))
        if self.publish_foreground:  # the foreground images: on demand too
            foreground.publish_images(
                {name: self.pubs[name] for name in ('mask', 'color', 'depth')},
                lambda: people_labels(out.foregrounds, out.depth_masked.shape),
                out.color_masked, out.depth_masked, depth_msg.encoding, header)
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(PipelineNode, args)
