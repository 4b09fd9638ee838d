"""The ROS4HRI (REP 155) bodies beside our own topics, published by the `ik` and `pipeline` nodes
(through `ik.SkeletonOutputs`), for HRI stacks (PAL's hri_* packages, libhri/pyhri, the RViz
HRI plugins).

Publications (each message with the source colour image's header)
    humans/bodies/tracked (hri_msgs/IdsList: the ids of the bodies in view, every frame, empty
    when nobody is)
    humans/bodies/<id>/skeleton2d (hri_msgs/Skeleton2D: 18 normalised COCO keypoints, those we
    have no joint for with confidence 0)
    humans/bodies/<id>/roi (hri_msgs/NormalizedRegionOfInterest2D: the joints' box)
    /tf: body_<id> in the camera's frame and the body's links in it (`core.hri.body_transforms`),
    in the same TFMessage as the joints' frames
    (each built and sent only while it has a subscriber; a body's publishers are made when it
    comes into view and destroyed hri.forget_after_s after it was last in view)
Parameters
    hri.publish, hri.body_id_prefix, hri.forget_after_s
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hri_msgs.msg import IdsList, NormalizedRegionOfInterest2D, Skeleton2D
from rclpy.node import Node
from rclpy.publisher import Publisher
from std_msgs.msg import Header

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.hri import (
    Transform,
    body_id,
    body_roi,
    body_transforms,
    id_prefix_problem,
    skeleton2d,
)
from pose4d_ros.core.joints import JointSet
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.params import Param
from pose4d_ros.wire import ids_list_to_cdr, roi_to_cdr, skeleton2d_to_cdr, stamp_to_ns

PARAMS = (
    Param('hri.publish', True, 'Publish the ROS4HRI (REP 155) bodies: humans/bodies/tracked, '
          "each body's skeleton2d and roi, its body_<id> frames on /tf.",
          restart='it decides at start-up whether the humans/bodies publishers are made'),
    Param('hri.body_id_prefix', 'b', 'First part of the REP 155 body ids, '
          '<prefix><track_id> (e.g. b1): a letter, then letters or digits.',
          check=id_prefix_problem, restart='a body keeps its id as long as it is tracked'),
    Param('hri.forget_after_s', 2.0, "Seconds (of the images' stamps) after a body was last "
          "in view when its skeleton2d and roi publishers are destroyed.",
          range=(0.0, 3600.0), live=True),
)


@dataclass
class _Body:
    """One body's REP 155 publishers."""
    id: str
    skeleton2d: Publisher
    roi: Publisher
    last_ns: int


class HriOutputs:
    """The REP 155 bodies of the people in view; see the module docstring."""

    def __init__(self, node: Node, p: dict[str, Any]) -> None:
        self.node = node
        self.prefix = p['hri.body_id_prefix']
        self.tracked = node.create_publisher(IdsList, 'humans/bodies/tracked', qos.OUTPUT_QOS)
        self.bodies: dict[int, _Body] = {}
        self.configure(p)

    def configure(self, p: dict[str, Any]) -> None:
        self.forget_ns = int(p['hri.forget_after_s'] * 1e9)

    def _body(self, track_id: int, stamp: int) -> _Body:
        body = self.bodies.get(track_id)
        if body is None:
            name = body_id(track_id, self.prefix)
            pub = self.node.create_publisher
            body = self.bodies[track_id] = _Body(
                name, pub(Skeleton2D, f'humans/bodies/{name}/skeleton2d', qos.OUTPUT_QOS),
                pub(NormalizedRegionOfInterest2D, f'humans/bodies/{name}/roi', qos.OUTPUT_QOS),
                stamp)
        body.last_ns = stamp
        return body

    def publish(self, people: list[JointSet], header: Header,
                intrinsics: Intrinsics | None) -> None:
        """The ids in view, and each body's skeleton2d and roi (normalised by the image's size:
        none without the camera's calibration)."""
        stamp = stamp_to_ns(header.stamp)
        ids = []
        for joints in people:
            body = self._body(joints.track_id, stamp)
            ids.append(body.id)
            if intrinsics is None:
                continue
            size = (intrinsics.width, intrinsics.height)
            if body.skeleton2d.get_subscription_count():
                body.skeleton2d.publish(skeleton2d_to_cdr(skeleton2d(joints, *size), header))
            if body.roi.get_subscription_count() and (roi := body_roi(joints, *size)):
                body.roi.publish(roi_to_cdr(roi, header))
        if self.tracked.get_subscription_count():
            self.tracked.publish(ids_list_to_cdr(ids, header))
        for track_id, body in list(self.bodies.items()):
            # gone for long enough, or the stamps went back (a looping bag: tracks start anew)
            if stamp - body.last_ns > self.forget_ns or stamp < body.last_ns:
                self.node.destroy_publisher(body.skeleton2d)
                self.node.destroy_publisher(body.roi)
                del self.bodies[track_id]

    def transforms(self, people: list[JointSet], frame_id: str) -> list[Transform]:
        """Every person's REP 155 frames (`core.hri.body_transforms`), for /tf."""
        return [t for joints in people
                for t in body_transforms(joints, frame_id, body_id(joints.track_id, self.prefix))]
