"""`detector`: 4D deformable part model (HOG on colour and depth) on the masked frame.

Finds the person's parts with the trained mixture-of-parts model, searching only the
foreground's box at the scale its depth gives (times the person's own scale factor, chosen per
track: `core.dpm.scale`), and lifts each part to 3-D with a robust depth look-up. Inputs are
paired by stamp and processed in order; a detector slower than the camera works on the newest
frames (at most two waiting, `common.STAGE_QUEUE`) and drops the others (counted) instead
of falling behind.

Subscriptions
    camera/color/image_raw (sensor_msgs/Image, rgb8/bgr8/mono8: the camera's; each person's
    search sees only their own mask's pixels)
    pose4d/foreground/depth (sensor_msgs/Image, 16UC1 mm or 32FC1 m)
    pose4d/foreground/mask (sensor_msgs/Image, mono8 labels, one value > 127 per person)
    camera/color/camera_info (sensor_msgs/CameraInfo; the latest, read as a frame is processed,
    `polled.LatestIntrinsics`)
One search per person of the mask (its labels, `core.people.people_from_labels`), each
person with their own detector state (`core.people.PeopleDetector`; kept while a person is
out of the mask as long as the tracker's defaults keep their track, or `detector.keep_unseen_s`
for a tracker whose `tracker.max_unseen_s` / `tracker.max_hidden_s` were changed), at most
`detector.max_people` a frame.

Publications (input header)
    pose4d/parts/people (pose4d_msgs/SkeletonArray: every person's parts, DETECTED or MISSING,
    track_id 0; in the mask's order, the best region first)
    pose4d/parts (pose4d_msgs/JointArray: the first person's, all MISSING when nobody; only
    while it has a subscriber: the tracker reads pose4d/parts/people)
    /diagnostics (also: people, people_over_limit: people in view beyond max_people, counted)
Parameters (config/detector.yaml)
    detector.model, detector.n_levels, detector.margin, detector.person_scales,
    detector.scale_warm_up_frames, detector.scale_probe_every, detector.min_confidence,
    detector.max_people, detector.quiet_frames, detector.keep_unseen_s, detector.arm_prior,
    detector.occluded_quantile, detector.colour_net, detector.colour_net_precision,
    detector.colour_net_weight, detector.colour_hog_weight, detector.colour_net_masked,
    lifecycle.autostart
    (`nodes.lifecycle`: a managed node)
    (a part's depth look-up is the model's: `core.lifting.lift_parts`)
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from pose4d_msgs.msg import JointArray, SkeletonArray
from sensor_msgs.msg import Image

from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.convnet import PRECISIONS, is_convnet, load_convnet
from pose4d_ros.core.dpm.infer import SearchConfig
from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.core.dpm.net_unary import NetUnary, UnaryConfig
from pose4d_ros.core.dpm.scale import ScaleConfig
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.people import PeopleDetector, TrackingConfig, people_from_labels
from pose4d_ros.core.stages import DetectorStage
from pose4d_ros.core.warm_up import warm_up_frame
from pose4d_ros.models import DEFAULT_COLOUR_NET, DEFAULT_NET_PRECISION, model_path
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.common import (
    PairedInputs,
    StageMonitor,
    run,
)
from pose4d_ros.nodes.lifecycle import AUTOSTART, ManagedNode
from pose4d_ros.nodes.params import Param, ParameterError
from pose4d_ros.nodes.polled import LatestIntrinsics
from pose4d_ros.wire import (
    color_from_msg,
    depth_from_msg,
    image_to_array,
    joints_to_cdr,
    skeletons_to_cdr,
    stamp_to_ns,
)

_S = SearchConfig()
_C = ScaleConfig()
_U = UnaryConfig()


def _model_exists(value: str) -> str | None:
    try:
        model_path(value)
    except FileNotFoundError as exc:
        return str(exc)
    return None


def _network_exists(value: str) -> str | None:
    if not value:
        return None
    try:
        path = model_path(value)
    except FileNotFoundError as exc:
        return str(exc)
    return None if is_convnet(path) else f'{path}: not a photograph network (core.convnet)'


def _scale_factors(value: list[float]) -> str | None:
    try:
        ScaleConfig(factors=tuple(value))
    except ValueError as exc:
        return str(exc)
    return None


def _precision(value: Any) -> str | None:
    return None if value in PRECISIONS else f'must be one of {", ".join(PRECISIONS)}'


PARAMS = (
    Param('detector.model', 'rgbd_14', 'Part model: the name of a shipped model (rgbd_14, '
          'rgbd_10, rgb_10, ...) or the path of a .npz.', check=_model_exists,
          restart='the model is loaded, and its kernels compiled, at start-up'),
    Param('detector.colour_net', DEFAULT_COLOUR_NET, "A photograph network (a shipped name "
          "such as lspet_convnet, or a .npz) whose joint heat maps, read on the search's crop, "
          "join each part's colour unary in the part model's tree (core.dpm.net_unary); '' = "
          "the model's colour HOG filters alone.", check=_network_exists,
          restart='the network is loaded at start-up'),
    Param('detector.colour_net_precision', DEFAULT_NET_PRECISION, "The network's arithmetic: "
          'int8 (its 8-bit twin, pose4d quantize-convnet: a third of the CPU on CPUs with '
          'VNNI) or fp32.',
          check=_precision, restart='the network is loaded at start-up'),
    Param('detector.colour_net_weight', _U.weight, "Factor on the network's log-probability "
          "in a part's unary (with detector.colour_net).", range=(0.0, 1000.0),
          restart='the network term is built at start-up'),
    Param('detector.colour_hog_weight', _U.hog_weight, "Factor on the model's colour HOG "
          'filters when detector.colour_net is set (0 = the network is the whole colour '
          'unary; the depth filters keep theirs).', range=(0.0, 10.0),
          restart="the model's filters are prepared at start-up"),
    Param('detector.colour_net_masked', _U.masked, 'The network reads each person blanked '
          'outside their mask, as the part model does (false: the camera image around them '
          'too).', restart='the network term is built at start-up'),
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
    Param('detector.max_people', TrackingConfig.max_people, 'People searched per frame at '
          'most (the best regions of the mask first); more in view are counted on /diagnostics '
          '(people_over_limit).', range=(1, 16), live=True),
    Param('detector.quiet_frames', TrackingConfig.quiet_frames, 'A region that scored under '
          "the tracker's birth score and has not moved (90 % of its pixels the same, depth "
          'within 5 cm) keeps its last detection this many frames before it is searched '
          'again; 0 = every region searched every frame.', range=(0, 30), live=True),
    Param('detector.keep_unseen_s', TrackingConfig.detector_keep_s, "How long a person's "
          'detector state (their person scale, the arm prior) is kept while they are unseen, '
          'seconds: a person back within it is searched as before, later as a new track (three '
          'person scales). 0 = as long as the tracker keeps a track by default (the longer of '
          'tracker.max_unseen_s and tracker.max_hidden_s; in the pipeline node, of their '
          'values); set it to match when those are changed on the tracker node.',
          range=(0.0, 60.0), live=True),
    Param('detector.arm_prior', _S.arm_prior, "Weight of the previous frame's elbows and "
          'wrists (at most 0.25 s old) when each arm is chosen among the few best the part model '
          'allows, per squared person scale of distance; 0 = the part model alone.',
          range=(0.0, 100.0), live=True),
    Param('detector.occluded_quantile', _S.occluded_quantile, 'Where a nearer person hides the '
          "one searched, each part scores at least this quantile of its responses on that "
          "person's own pixels, so a hidden part may lie behind the nearer person instead of "
          'the whole pose being pulled onto the visible half; 0 = off.', range=(0.0, 1.0),
          live=True),
    AUTOSTART,
)


def detector_settings(p: dict[str, Any]) -> dict[str, Any]:
    """The live settings of the detector stage (`DetectorStage.configure`) from the
    parameters (also used by the pipeline node)."""
    return {'search': SearchConfig(n_levels=p['detector.n_levels'], margin=p['detector.margin'],
                                   arm_prior=p['detector.arm_prior'],
                                   occluded_quantile=p['detector.occluded_quantile']),
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
    return DetectorStage(model, **detector_settings(p), unary=colour_net(p))


def colour_net(p: dict[str, Any]) -> NetUnary | None:
    """The photograph network as a colour unary (`detector.colour_net`), or None."""
    if not p['detector.colour_net']:
        return None
    path = model_path(p['detector.colour_net'])
    try:
        net = load_convnet(path, p['detector.colour_net_precision'])
    except (OSError, ValueError) as exc:
        raise ParameterError(f'parameter detector.colour_net: {exc}') from None
    return NetUnary(net, UnaryConfig(weight=p['detector.colour_net_weight'],
                                     hog_weight=p['detector.colour_hog_weight'],
                                     masked=p['detector.colour_net_masked']))


def people_config(p: dict[str, Any]) -> TrackingConfig:
    return TrackingConfig(max_people=p['detector.max_people'],
                          quiet_frames=p['detector.quiet_frames'],
                          detector_keep_s=p['detector.keep_unseen_s'])


class DetectorNode(ManagedNode):
    """Detects every person's parts; see the module docstring."""

    def __init__(self) -> None:
        super().__init__('detector', PARAMS, check=detector_settings)

    def configure(self, p: dict[str, Any]) -> None:
        self.template = detector_stage(p)
        self.template.warm_up(cad60_intrinsics())  # compile before the first camera frame
        self.people = PeopleDetector(self.template, people_config(p))
        color, depth, mask = warm_up_frame(cad60_intrinsics())  # the several-person path too
        for stamp_s in (0.0, 1 / 30):
            self.people.step(color, depth, cad60_intrinsics(),
                             people_from_labels(mask.astype(np.uint8) * 255, depth),
                             stamp_s=stamp_s)
        self.people.reset()
        self.monitor = StageMonitor(self, 'detector')
        self.monitor.values.update(people=0, people_over_limit=0)
        self.pub_people = self.create_publisher(SkeletonArray, 'pose4d/parts/people',
                                                qos.OUTPUT_QOS)
        self.pub = self.create_publisher(JointArray, 'pose4d/parts', qos.OUTPUT_QOS)

    def activate(self, p: dict[str, Any]) -> None:
        self.camera = LatestIntrinsics(self, self.monitor)
        # the camera's colour, masked here person by person (`PeopleDetector`): the
        # foreground publishes its mask and depth, not a masked copy of the colour image
        self.inputs = PairedInputs(
            self, [(Image, topic, qos.SENSOR_QOS) for topic in (
                'camera/color/image_raw', 'pose4d/foreground/depth', 'pose4d/foreground/mask')],
            self.process, self.monitor)
        net = Path(str(p['detector.colour_net'])).name
        self.get_logger().info(
            f'detecting {len(self.template.names)} parts with '
            f'{Path(str(p["detector.model"])).name} ({self.template.model.channels}'
            f'{", colour net " + net if net else ""}) in '
            f'{self.resolve_topic_name("camera/color/image_raw")} masked by '
            f'{self.resolve_topic_name("pose4d/foreground")} -> '
            f'{self.resolve_topic_name("pose4d/parts")}(/people), up to '
            f'{p["detector.max_people"]} people')

    def process(self, items: Any) -> None:
        if (p := self.params.changes()) is not None:
            self.people.configure(**detector_settings(p))
            self.people.config = people_config(p)
        color_msg, depth_msg, mask_msg = items
        t0 = time.perf_counter()
        stamp = stamp_to_ns(color_msg.header.stamp)
        if self.monitor.time_jumped(stamp):
            self.people.reset()
        try:
            color = color_from_msg(color_msg)
            depth = depth_from_msg(depth_msg)
            labels = image_to_array(mask_msg)
            if labels.ndim != 2 or not color.shape[:2] == depth.shape == labels.shape:
                raise ValueError(f'colour {color.shape[:2]}, depth {depth.shape} and mask '
                                 f'{labels.shape} differ in size')
            # the foreground's labels (`people_labels`); a plain mask (255 = person) is one
            people = people_from_labels(labels, depth, lowest=128)
            parts = self.people.step(color, depth, self.camera.latest(), people,
                                     stamp_s=stamp * 1e-9)
        except ValueError as exc:
            self.monitor.bad_input(f'frame at {stamp} ns refused: {exc}')
            return
        values = self.monitor.values
        values['people'] = len(parts)
        values['people_over_limit'] += max(len(people) - len(parts), 0)
        header = color_msg.header
        # everyone first: a tracker that hears both leaves the single person out
        self.pub_people.publish(skeletons_to_cdr(parts, header))
        if self.pub.get_subscription_count():  # the primary person alone: on demand
            self.pub.publish(joints_to_cdr(parts[0] if parts else
                                           JointSet.missing(self.template.names), header))
        self.monitor.frame(stamp, time.perf_counter() - t0)


def main(args: list[str] | None = None) -> int:
    return run(DetectorNode, args)
