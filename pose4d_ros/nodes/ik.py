"""`ik`: complete the skeleton with inverse kinematics (eqs. 17-24): 14 joints in 3-D.

Elbows and knees come from shoulders/hips and wrists/ankles in 3-D and the bone lengths (fixed
parameters, or learned per track); the swivel angle on the circle of possible elbows is chosen by
the depth image of the person, with a joint-limit prior where depth cannot tell. Tracked parts
and depth are paired by stamp (exact, or nearest within `ik.depth_slop_s`).

Subscriptions
    pose4d/parts/tracked (pose4d_msgs/JointArray, 10 parts)
    pose4d/foreground/depth (sensor_msgs/Image, 16UC1 or 32FC1; only when ik.use_depth)
    camera/color/camera_info (sensor_msgs/CameraInfo; the latest)
Publications
    pose4d/skeleton (pose4d_msgs/JointArray, 14 joints, input header)
    pose4d/skeleton/markers (visualization_msgs/MarkerArray, joints and bones by source)
    /tf (tf2_msgs/TFMessage: each located joint as the frame <tf.prefix>/<track_id>/<joint>
    in the image's frame, stamped like the skeleton; when tf.publish)
    /diagnostics
    (markers and /tf are built and sent only while they have a subscriber)
Parameters (config/ik.yaml)
    ik.use_depth, ik.learn_lengths, ik.upper_arm_length_m, ik.forearm_length_m,
    ik.thigh_length_m, ik.shin_length_m, ik.depth_slop_s, ik.marker_lifetime_s, tf.publish,
    tf.prefix
"""

from __future__ import annotations

import time
from typing import Any

from pose4d_msgs.msg import JointArray
from rclpy.node import Node
from sensor_msgs.msg import Image
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.kinematics import DEFAULT_LIMB_LENGTHS_M
from pose4d_ros.core.pipeline import IkStage
from pose4d_ros.core.skeleton import limb_bones
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import (
    LatestIntrinsics,
    PairedInputs,
    StageMonitor,
    run,
    subscribe,
)
from pose4d_ros.nodes.convert import (
    depth_from_msg,
    joints_from_msg,
    joints_to_cdr,
    joints_to_tf,
    skeleton_markers,
    stamp_to_ns,
)
from pose4d_ros.nodes.params import NodeParams, Param


def _frame_prefix(value: str) -> str | None:
    if value.startswith('/') or value.endswith('/') or any(c.isspace() for c in value):
        return f'{value!r}: a TF frame name has no leading or trailing / and no spaces'
    return None


_ARM, _LEG = DEFAULT_LIMB_LENGTHS_M['left_arm'], DEFAULT_LIMB_LENGTHS_M['left_leg']
PARAMS = (
    Param('ik.use_depth', IkStage.USE_DEPTH, 'Choose the elbow/knee swivel with the depth image '
          '(pose4d/foreground/depth); false = joint-limit prior only, no depth subscription.',
          restart='it decides at start-up whether depth is subscribed to'),
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
    return IkStage(use_depth=p['ik.use_depth'], **ik_settings(p))


class SkeletonOutputs:
    """The skeleton's publications, the same in the ik and pipeline nodes: pose4d/skeleton,
    its RViz markers and its joints on /tf."""

    def __init__(self, node: Node, p: dict[str, Any]) -> None:
        self.bones = limb_bones()
        self.skeleton = node.create_publisher(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        self.markers = node.create_publisher(MarkerArray, 'pose4d/skeleton/markers',
                                             qos.OUTPUT_QOS)
        self.tf = node.create_publisher(TFMessage, '/tf', qos.TF_QOS)
        self.configure(p)

    def configure(self, p: dict[str, Any]) -> None:
        self.marker_lifetime_s = p['ik.marker_lifetime_s']
        self.publish_tf = p['tf.publish']
        self.tf_prefix = p['tf.prefix']

    def publish(self, skeleton: JointSet, header: Header) -> None:
        self.skeleton.publish(joints_to_cdr(skeleton, header))
        # markers and transforms are built only while someone listens: making and serialising
        # them costs more CPU than the IK itself
        if self.markers.get_subscription_count():
            self.markers.publish(skeleton_markers(skeleton, self.bones, header,
                                                  lifetime_s=self.marker_lifetime_s))
        if self.publish_tf and self.tf.get_subscription_count():
            frames = joints_to_tf(skeleton, header, self.tf_prefix)
            if frames.transforms:
                self.tf.publish(frames)


class IkNode(Node):
    """Completes the tracked parts to a 14-joint skeleton; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('ik')
        self.params = NodeParams(self, PARAMS, check=ik_settings)
        p = self.params.values
        self.stage = ik_stage(p)
        self.stage.warm_up(cad60_intrinsics())  # compile before the first frame
        self.monitor = StageMonitor(self, 'ik')
        self.camera = LatestIntrinsics(self, self.monitor)
        self.outputs = SkeletonOutputs(self, p)
        if self.stage.use_depth:
            self.inputs = PairedInputs(
                self, [(JointArray, 'pose4d/parts/tracked', qos.INPUT_QOS),
                       (Image, 'pose4d/foreground/depth', qos.SENSOR_QOS)],
                lambda items: self.process(*items), self.monitor,
                slop_ns=int(p['ik.depth_slop_s'] * 1e9))
        else:
            subscribe(self, JointArray, 'pose4d/parts/tracked',
                      lambda m: self.process(m, None), qos.INPUT_QOS, self.monitor)
        self.get_logger().info(
            f'completing {self.resolve_topic_name("pose4d/parts/tracked")} -> '
            f'{self.resolve_topic_name("pose4d/skeleton")} (depth: {self.stage.use_depth}, '
            f'learn lengths: {p["ik.learn_lengths"]}, joints on /tf: {p["tf.publish"]})')

    def process(self, msg: JointArray, depth_msg: Image | None) -> None:
        if (p := self.params.changes()) is not None:
            self.stage.configure(**ik_settings(p))
            self.outputs.configure(p)
        t0 = time.perf_counter()
        stamp = stamp_to_ns(msg.header.stamp)
        if self.monitor.time_jumped(stamp):
            self.stage.reset()
        try:
            depth = depth_from_msg(depth_msg) if depth_msg is not None else None
            skeleton = self.stage.step(joints_from_msg(msg), depth, self.camera.intrinsics)
        except ValueError as exc:
            self.monitor.bad_input(f'frame at {stamp} ns refused: {exc}')
            return
        self.outputs.publish(skeleton, msg.header)
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(IkNode, args)
