"""`foreground`: the person's mask from the depth image (floor removal + MSER), applied.

The people are found on the depth image alone. The colour camera's camera_info (its stamp
and frame are the colour image's) and the depth image are paired by stamp (exact, or nearest
within `foreground.slop_s`), never "the latest depth", and processed in order; two frames at
most wait to be processed (`common.STAGE_QUEUE`), so a stage slower than the camera works on
the newest frames and drops the older ones (counted on /diagnostics).

Subscriptions
    camera/color/camera_info (sensor_msgs/CameraInfo)
    camera/depth/image_raw (sensor_msgs/Image, 16UC1 mm or 32FC1 m, registered to colour)
    camera/color/image_raw (sensor_msgs/Image, rgb8/bgr8/mono8; only while the masked colour
    or the point cloud has a subscriber: the image of a frame's stamp if it has come, never
    waited for, `polled.RecentImages`)
Every person region is a candidate (`core.foreground.segment_people`, at most `MAX_PEOPLE`,
best first); the mask tells them apart.

Publications (all with the colour image's header)
    pose4d/foreground/mask (mono8 labels: 0 = background, 255 = the best person, 254 the next
    one, ... (`core.people.people_labels`): `mask > 0` is everyone, and one person's mask is
    255 = person as before)
    pose4d/foreground/color (rgb8, 0 outside the people; only while it has a subscriber, and
    for a frame whose colour image has come: the detector reads the camera's colour and masks
    it itself)
    pose4d/foreground/depth (the input's encoding; 0 / NaN outside the people)
    pose4d/foreground/points (sensor_msgs/PointCloud2 of the people, if
    foreground.publish_cloud and while it has a subscriber)
    /diagnostics (also: people, the person regions found in the last frame)
Parameters (config/foreground.yaml)
    foreground.max_region_area_px, foreground.mser_delta, foreground.mser_max_variation,
    foreground.depth_near_m, foreground.depth_far_m, foreground.floor_remove,
    foreground.temporal, foreground.slop_s, foreground.publish_cloud, foreground.cloud_step,
    foreground.depth_shift_px, lifecycle.autostart (`nodes.lifecycle`: a managed node)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

from pose4d_ros.core.camera import backproject, cad60_intrinsics, depth_to_millimetres
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.people import people_labels
from pose4d_ros.core.stages import ForegroundStage
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import (
    PairedInputs,
    StageMonitor,
    camera_depth,
    pixel_pair,
    run,
)
from pose4d_ros.nodes.convert import cloud_to_msg
from pose4d_ros.nodes.lifecycle import AUTOSTART, ManagedNode
from pose4d_ros.nodes.params import Param
from pose4d_ros.nodes.polled import RecentImages
from pose4d_ros.wire import (
    color_from_msg,
    image_to_cdr,
    intrinsics_from_msg,
    stamp_to_ns,
)

_F = ForegroundConfig()
# Person regions published at most per frame (the detector's max_people bounds its work)
MAX_PEOPLE = 16


PARAMS = (
    Param('foreground.max_region_area_px', _F.max_region_area_px, 'The background area '
          'threshold: stable regions larger than this are background, pixels.',
          range=(100, 10_000_000), live=True),
    Param('foreground.mser_delta', _F.mser_delta, 'MSER stability step, 8-bit depth levels.',
          range=(1, 64), live=True),
    Param('foreground.mser_max_variation', _F.mser_max_variation, "MSER stability score: "
          'largest relative area change over +-delta levels.', range=(0.01, 10.0), live=True),
    Param('foreground.depth_near_m', _F.depth_near_m, 'Nearest depth mapped to 8 bits, '
          'metres.', range=(0.0, 10.0), live=True),
    Param('foreground.depth_far_m', _F.depth_far_m, 'Farthest depth mapped to 8 bits, metres.',
          range=(0.1, 20.0), live=True),
    Param('foreground.floor_remove', _F.floor_remove, 'Fit the floor plane (RANSAC) and drop '
          'it before MSER.', live=True),
    Param('foreground.temporal', ForegroundStage.TEMPORAL,
          "Prefer regions overlapping the previous frame's "
          'person and reuse its floor plane.', live=True),
    Param('foreground.slop_s', 0.0, 'Largest stamp difference between colour and depth, '
          'seconds (0 = the same stamp).', range=(0.0, 1.0),
          restart='the pairing of colour and depth is set up at start-up'),
    Param('foreground.publish_cloud', False, "Publish the person's pixels as a PointCloud2 "
          '(pose4d/foreground/points).',
          restart='it decides at start-up whether the cloud has a publisher'),
    Param('foreground.cloud_step', 2, 'Pixel stride of the point cloud.', range=(1, 16),
          live=True),
    Param('foreground.depth_shift_px', [0, 0], "[dx, dy]: move the camera's depth image by "
          'this many pixels (x right, y down) onto its colour image, for a camera whose depth '
          "is registered off (`pose4d eval` of a recording gives the shift its edges suggest: "
          "registration); what the foreground publishes, and the detector reads, is moved.",
          check=pixel_pair, live=True),
    AUTOSTART,
)


# colour, depth and camera_info of one stamp (the pivot, colour, first): the pipeline node's
CAMERA_TOPICS = [(Image, 'camera/color/image_raw', qos.SENSOR_QOS),
                 (Image, 'camera/depth/image_raw', qos.SENSOR_QOS),
                 (CameraInfo, 'camera/color/camera_info', qos.SENSOR_QOS)]
# the foreground node's: the colour camera's calibration (the pivot) and the depth image
DEPTH_TOPICS = [CAMERA_TOPICS[2], CAMERA_TOPICS[1]]


def foreground_settings(p: dict[str, Any]) -> dict[str, Any]:
    """The live settings of the foreground stage (`ForegroundStage.configure`) from the
    parameters (also used by the pipeline node)."""
    config = replace(ForegroundConfig(), max_region_area_px=p['foreground.max_region_area_px'],
                     mser_delta=p['foreground.mser_delta'],
                     mser_max_variation=p['foreground.mser_max_variation'],
                     depth_near_m=p['foreground.depth_near_m'],
                     depth_far_m=p['foreground.depth_far_m'],
                     floor_remove=p['foreground.floor_remove'])
    return {'config': config, 'temporal': p['foreground.temporal']}


def foreground_stage(p: dict[str, Any]) -> ForegroundStage:
    """The foreground stage configured by the parameters (also used by the pipeline node)."""
    return ForegroundStage(**foreground_settings(p))


def publish_images(pubs: dict[str, Any], labels: Callable[[], np.ndarray],
                   color_m: np.ndarray, depth_m: np.ndarray, encoding: str, header: Header, *,
                   always: tuple[str, ...] = ()) -> None:
    """Publish the foreground images on `pubs` ('mask', 'color', 'depth': the publishers
    there are): those named in `always` every frame, the others only while something
    subscribes, each serialised only when published (`wire.image_to_cdr`). `labels()`: the
    people's label image (`core.people.people_labels`); the depth goes out in the input's
    `encoding` (32FC1 metres, else 16UC1 millimetres)."""
    for name, pub in pubs.items():
        if name not in always and not pub.get_subscription_count():
            continue
        if name == 'mask':
            pub.publish(image_to_cdr(labels(), 'mono8', header))
        elif name == 'color':
            pub.publish(image_to_cdr(color_m, 'rgb8', header))
        elif encoding == '32FC1':
            pub.publish(image_to_cdr(depth_m, '32FC1', header))
        else:
            pub.publish(image_to_cdr(depth_to_millimetres(depth_m), '16UC1', header))


class ForegroundNode(ManagedNode):
    """Masks the person in each RGB-D frame; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('foreground', PARAMS, check=foreground_settings)

    def configure(self, p: dict[str, Any]) -> None:
        self.stage = foreground_stage(p)
        self.publish_cloud = p['foreground.publish_cloud']
        self.cloud_step = p['foreground.cloud_step']
        self.depth_shift = p['foreground.depth_shift_px']
        self.stage.warm_up(cad60_intrinsics())  # compile before the first camera frame
        self.monitor = StageMonitor(self, 'foreground')
        self.pubs = {name: self.create_publisher(Image, f'pose4d/foreground/{name}',
                                                 qos.OUTPUT_QOS)
                     for name in ('mask', 'color', 'depth')}
        self.pub_cloud = (self.create_publisher(PointCloud2, 'pose4d/foreground/points',
                                                qos.OUTPUT_QOS) if self.publish_cloud else None)

    def activate(self, p: dict[str, Any]) -> None:
        slop_ns = int(p['foreground.slop_s'] * 1e9)
        self.inputs = PairedInputs(self, DEPTH_TOPICS, self.process, self.monitor,
                                   slop_ns=slop_ns)
        self.color = RecentImages(self, self.monitor, 'camera/color/image_raw', color_from_msg,
                                  slop_ns=slop_ns, wanted=self._colour_wanted)
        self.get_logger().info(
            f'masking {self.resolve_topic_name("camera/color/image_raw")} + '
            f'{self.resolve_topic_name("camera/depth/image_raw")} -> '
            f'{self.resolve_topic_name("pose4d/foreground")} (background area > '
            f'{self.stage.config.max_region_area_px} px, floor removal '
            f'{self.stage.config.floor_remove})')

    def _colour_wanted(self) -> bool:
        """The colour image is read only for the masked colour and the point cloud."""
        return bool(self.pubs['color'].get_subscription_count() or (
            self.pub_cloud is not None and self.pub_cloud.get_subscription_count()))

    def process(self, items: Any) -> None:
        if (p := self.params.changes()) is not None:
            self.stage.configure(**foreground_settings(p))
            self.cloud_step = p['foreground.cloud_step']
            self.depth_shift = p['foreground.depth_shift_px']
        info_msg, depth_msg = items
        t0 = time.perf_counter()
        stamp = stamp_to_ns(info_msg.header.stamp)
        if self.monitor.time_jumped(stamp):
            self.stage.reset()
        try:
            color = self.color.at(stamp) if self._colour_wanted() else None
            intrinsics = intrinsics_from_msg(info_msg)
            people, found, color_m, depth_m = self.stage.step_people(
                color, camera_depth(depth_msg, self.depth_shift), intrinsics, MAX_PEOPLE)
        except ValueError as exc:
            self.monitor.bad_input(f'frame at {stamp} ns refused: {exc}')
            return
        self.monitor.values['people'] = found
        header = info_msg.header
        labels = people_labels(people, depth_m.shape)
        # the masked colour only on demand: the detector reads the camera's and masks it
        pubs = self.pubs if color_m is not None else {
            k: pub for k, pub in self.pubs.items() if k != 'color'}
        publish_images(pubs, lambda: labels, color_m, depth_m, depth_msg.encoding, header,
                       always=('mask', 'depth'))
        if (color is not None and self.pub_cloud is not None
                and self.pub_cloud.get_subscription_count()):
            rows, cols = np.nonzero(labels[::self.cloud_step, ::self.cloud_step])
            rows, cols = rows * self.cloud_step, cols * self.cloud_step
            xyz = backproject(np.stack([cols, rows], axis=1), depth_m[rows, cols], intrinsics)
            ok = np.isfinite(xyz).all(axis=1)
            self.pub_cloud.publish(cloud_to_msg(xyz[ok], color[rows[ok], cols[ok]], header))
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(ForegroundNode, args)
