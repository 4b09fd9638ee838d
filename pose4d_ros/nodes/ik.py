"""`ik`: complete the skeleton with inverse kinematics (eqs. 17-24): 14 joints in 3-D.

Elbows and knees come from shoulders/hips and wrists/ankles in 3-D and the bone lengths (fixed
parameters, or learned per track); the swivel angle on the circle of possible elbows is chosen by
the depth image of the person, with a joint-limit prior where depth cannot tell; `ik.method`
picks the law-of-cosines circle or the paper's Denavit-Hartenberg chains. The depth image is
the foreground's of the tracked parts' stamp (exact, or nearest within `ik.depth_slop_s`),
taken when the parts come and never waited for: the foreground publishes it before the
detector starts on that frame (a frame without it is completed by the limb prior).

Several people: one IK per track id, each with its own learned bone lengths. Frames are
completed in a worker thread: an IK slower than its input works on the newest frame and drops
the older ones (counted as `dropped` on /diagnostics), never queueing them.

Subscriptions
    pose4d/parts/tracked/people (pose4d_msgs/SkeletonArray, every tracked person), or from a
    tracker that publishes only one person, pose4d/parts/tracked (pose4d_msgs/JointArray;
    subscribed only while nothing publishes pose4d/parts/tracked/people)
    pose4d/foreground/depth (sensor_msgs/Image, 16UC1 or 32FC1; only when ik.use_depth; read
    as the parts come, `polled.RecentImages`)
    camera/color/camera_info (sensor_msgs/CameraInfo; the latest, read as the parts come,
    `polled.LatestIntrinsics`)
Publications
    pose4d/skeletons (pose4d_msgs/SkeletonArray: every person's 14 joints, the primary first;
    empty when nobody is in view)
    pose4d/skeleton (pose4d_msgs/JointArray, 14 joints, input header: the primary person's,
    the longest-tracked one in view; all MISSING with track_id 0 when nobody is)
    pose4d/skeleton/markers (visualization_msgs/MarkerArray, joints by source; with several
    people each in the namespace pose4d/<track_id>, bones in the id's colour)
    /tf (tf2_msgs/TFMessage: each located joint as the frame <tf.prefix>/<track_id>/<joint>
    in the image's frame, stamped like the skeleton; when tf.publish)
    humans/bodies/tracked, humans/bodies/<id>/{skeleton2d,roi} and the body_<id> frames on /tf:
    the ROS4HRI (REP 155) bodies (`nodes.hri`; when hri.publish)
    /diagnostics
    (markers, /tf and the REP 155 bodies are built and sent only while they have a subscriber)
Parameters (config/ik.yaml)
    ik.use_depth, ik.method, ik.learn_lengths, ik.upper_arm_length_m, ik.forearm_length_m,
    ik.thigh_length_m, ik.shin_length_m, ik.depth_slop_s, ik.marker_lifetime_s, tf.publish,
    tf.prefix, hri.publish, hri.body_id_prefix, hri.forget_after_s, lifecycle.autostart
    (`nodes.lifecycle`: a managed node)
"""

from __future__ import annotations

import time
from typing import Any

from pose4d_msgs.msg import JointArray, SkeletonArray
from rclpy.node import Node
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics
from pose4d_ros.core.joints import MISSING, JointSet
from pose4d_ros.core.kinematics import DEFAULT_LIMB_LENGTHS_M
from pose4d_ros.core.people import PeopleIk
from pose4d_ros.core.skeleton import SKELETON_14, limb_bones
from pose4d_ros.core.stages import IkStage
from pose4d_ros.nodes import hri, qos
from pose4d_ros.nodes.common import (
    PeopleInputs,
    StageMonitor,
    run,
)
from pose4d_ros.nodes.convert import people_markers, skeleton_markers
from pose4d_ros.nodes.lifecycle import AUTOSTART, ManagedNode
from pose4d_ros.nodes.params import Param
from pose4d_ros.nodes.polled import LatestIntrinsics, RecentImages
from pose4d_ros.wire import depth_from_msg, joints_to_cdr, skeletons_to_cdr, stamp_to_ns, tf_to_cdr


def _frame_prefix(value: str) -> str | None:
    if value.startswith('/') or value.endswith('/') or any(c.isspace() for c in value):
        return f'{value!r}: a TF frame name has no leading or trailing / and no spaces'
    return None


_ARM, _LEG = DEFAULT_LIMB_LENGTHS_M['left_arm'], DEFAULT_LIMB_LENGTHS_M['left_leg']
PARAMS = (
    Param('ik.use_depth', IkStage.USE_DEPTH, 'Choose the elbow/knee swivel with the depth image '
          '(pose4d/foreground/depth); false = joint-limit prior only, no depth subscription.',
          restart='it decides at start-up whether depth is subscribed to'),
    Param('ik.method', IkStage.METHOD, "How elbows and knees are solved: 'geometric' (the "
          "law-of-cosines circle) or 'dh' (the paper's Denavit-Hartenberg chains, eqs. 17-24, "
          'with joint limits as angles); both choose the swivel by depth, then the prior.',
          choices=IkStage.METHODS, restart='the solver is chosen at start-up'),
    Param('ik.learn_lengths', IkStage.LEARN,
          "Learn each track's bone lengths from the observed reach; "
          'false = the fixed lengths below.', live=True),
    Param('ik.upper_arm_length_m', _ARM[0], 'Shoulder-elbow length, metres.',
          range=(0.05, 1.0), live=True),
    Param('ik.forearm_length_m', _ARM[1], 'Elbow-wrist length, metres.', range=(0.05, 1.0),
          live=True),
    Param('ik.thigh_length_m', _LEG[0], 'Hip-knee length, metres.', range=(0.05, 1.5), live=True),
    Param('ik.shin_length_m', _LEG[1], 'Knee-ankle length, metres.', range=(0.05, 1.5), live=True),
    Param('ik.depth_slop_s', 0.0, 'Largest stamp difference between tracked parts and depth, '
          'seconds (0 = the same stamp).', range=(0.0, 1.0),
          restart='the pairing of parts and depth is set up at start-up'),
    Param('ik.marker_lifetime_s', 0.5, 'Lifetime of the RViz markers, seconds.',
          range=(0.0, 60.0), live=True),
    Param('tf.publish', True, 'Publish each located joint of the skeleton on /tf.', live=True),
    Param('tf.prefix', 'pose4d', 'First part of the joints\' TF frame names, '
          '<prefix>/<track_id>/<joint>.', check=_frame_prefix, live=True),
    *hri.PARAMS,
    AUTOSTART,
)


def ik_settings(p: dict[str, Any]) -> dict[str, Any]:
    """The live settings of the IK stage (`IkStage.configure`) from the parameters (also used
    by the pipeline node)."""
    arm = (p['ik.upper_arm_length_m'], p['ik.forearm_length_m'])
    leg = (p['ik.thigh_length_m'], p['ik.shin_length_m'])
    return {'lengths': {'left_arm': arm, 'right_arm': arm, 'left_leg': leg, 'right_leg': leg},
            'learn': p['ik.learn_lengths']}


def ik_stage(p: dict[str, Any]) -> IkStage:
    """The IK stage configured by the parameters (also used by the pipeline node)."""
    return IkStage(use_depth=p['ik.use_depth'], method=p['ik.method'], **ik_settings(p))


class SkeletonOutputs:
    """The skeletons' publications, the same in the ik and pipeline nodes: pose4d/skeletons
    (everyone), pose4d/skeleton (the primary person), their RViz markers and joints on /tf,
    and the REP 155 bodies (`nodes.hri`)."""

    def __init__(self, node: Node, p: dict[str, Any]) -> None:
        self.bones = limb_bones()
        self.skeletons = node.create_publisher(SkeletonArray, 'pose4d/skeletons',
                                               qos.OUTPUT_QOS)
        self.skeleton = node.create_publisher(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        self.markers = node.create_publisher(MarkerArray, 'pose4d/skeleton/markers',
                                             qos.OUTPUT_QOS)
        self.tf = node.create_publisher(TFMessage, '/tf', qos.TF_QOS)
        self.hri = hri.HriOutputs(node, p) if p['hri.publish'] else None
        self.configure(p)

    def configure(self, p: dict[str, Any]) -> None:
        self.marker_lifetime_s = p['ik.marker_lifetime_s']
        self.publish_tf = p['tf.publish']
        self.tf_prefix = p['tf.prefix']
        if self.hri is not None:
            self.hri.configure(p)

    def publish(self, people: list[JointSet], header: Header,
                intrinsics: Intrinsics | None = None) -> None:
        """Every person's skeleton (the primary first); nobody: an empty SkeletonArray and an
        all-MISSING skeleton of track 0 on pose4d/skeleton. `intrinsics`: the colour image's
        (its size normalises the REP 155 keypoints; without it they are not published)."""
        self.skeletons.publish(skeletons_to_cdr(people, header))
        primary = people[0] if people else JointSet.missing(SKELETON_14)
        self.skeleton.publish(joints_to_cdr(primary, header))
        # markers and transforms are built only while someone listens: making and serialising
        # them costs more CPU than the IK itself
        if self.markers.get_subscription_count():
            self.markers.publish(
                skeleton_markers(primary, self.bones, header,
                                 lifetime_s=self.marker_lifetime_s) if len(people) <= 1
                else people_markers(people, self.bones, header,
                                    lifetime_s=self.marker_lifetime_s))
        if self.hri is not None:
            self.hri.publish(people, header, intrinsics)
        if (self.publish_tf or self.hri is not None) and self.tf.get_subscription_count():
            bodies = self.hri.transforms(people, header.frame_id) if self.hri is not None else ()
            frames = tf_to_cdr(people if self.publish_tf else [], header, self.tf_prefix, bodies)
            if frames is not None:
                self.tf.publish(frames)


class IkNode(ManagedNode):
    """Completes every person's tracked parts to a 14-joint skeleton; see the module
    docstring."""

    def __init__(self) -> None:
        super().__init__('ik', PARAMS, check=ik_settings)

    def configure(self, p: dict[str, Any]) -> None:
        self.template = ik_stage(p)
        self.template.warm_up(cad60_intrinsics())  # compile before the first frame
        self.people = PeopleIk(self.template)
        self.monitor = StageMonitor(self, 'ik')
        self.monitor.values['people'] = 0
        self.outputs = SkeletonOutputs(self, p)

    def activate(self, p: dict[str, Any]) -> None:
        self.camera = LatestIntrinsics(self, self.monitor)
        self.depth = (RecentImages(self, self.monitor, 'pose4d/foreground/depth',
                                   depth_from_msg, slop_ns=int(p['ik.depth_slop_s'] * 1e9))
                      if self.template.use_depth else None)
        self.inputs = PeopleInputs(self, 'pose4d/parts/tracked/people', 'pose4d/parts/tracked',
                                   [], self.process, self.monitor)
        self.get_logger().info(
            f'completing {self.resolve_topic_name("pose4d/parts/tracked")}(/people) -> '
            f'{self.resolve_topic_name("pose4d/skeleton")}, '
            f'{self.resolve_topic_name("pose4d/skeletons")} (depth: {self.template.use_depth}, '
            f'learn lengths: {p["ik.learn_lengths"]}, joints on /tf: {p["tf.publish"]})')

    def process(self, tracked: list[JointSet], header: Header, _: tuple) -> None:
        if (p := self.params.changes()) is not None:
            self.people.configure(**ik_settings(p))
            self.outputs.configure(p)
        t0 = time.perf_counter()
        stamp = stamp_to_ns(header.stamp)
        if self.monitor.time_jumped(stamp):
            self.people.reset()
        # a single-person tracker's message of nobody (track 0, nothing located) is nobody
        tracked = [t for t in tracked if t.track_id or (t.source != MISSING).any()]
        intrinsics = self.camera.latest()
        if self.depth is not None and intrinsics is None:
            # not a bad input: the camera's calibration has not come yet (its reader may match
            # after the others'); the depth image cannot be read without it
            self.get_logger().info(
                f'no {self.resolve_topic_name("camera/color/camera_info")} yet: elbows and '
                'knees from the limb prior, without the depth image', throttle_duration_sec=5.0)
        try:
            # the foreground publishes a frame's depth before the detector starts on it: it
            # has come by the time the frame's tracked parts do
            depth = (self.depth.at(stamp) if self.depth is not None and intrinsics is not None
                     else None)
            skeletons = self.people.step(tracked, depth, intrinsics)
        except ValueError as exc:
            self.monitor.bad_input(f'frame at {stamp} ns refused: {exc}')
            return
        self.monitor.values['people'] = len(skeletons)
        self.outputs.publish(skeletons, header, intrinsics)
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(IkNode, args)
