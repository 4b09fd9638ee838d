"""`DetectorStage`: the 4D deformable part model (`core.dpm`) on the masked frame; each part's
pixel is lifted to 3-D with the robust depth of the person's pixels around it, plus the model's
learned depth offset from the visible surface to the joint centre."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import Intrinsics, backproject
from pose4d_ros.core.dpm.infer import Detector, SearchConfig
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.dpm.net_unary import NetUnary
from pose4d_ros.core.dpm.scale import PersonScale, ScaleConfig
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.lifting import lift_parts, medoid_parts
from pose4d_ros.core.stages._shared import _image_max, _read_only
from pose4d_ros.core.warm_up import warm_up_frame

# The previous frame's parts guide the detector's arms (`SearchConfig.arm_prior`) when it is
# at most this old, seconds (a 30 fps camera that drops a few frames; 10 fps recordings)
PRIOR_MAX_GAP_S = 0.25


class DetectorStage:
    """Part detection in one frame: the best pose of the part model, lifted to 3-D.

    Parameters
    ----------
    model : a trained part model (`core.dpm.model.load_model`); its channels say whether the
        depth HOG is used ('rgbd') or not ('rgb', the Yang & Ramanan baseline).
    search : where and at which scales to search (`core.dpm.infer.SearchConfig`).
    scale : how the person's own scale is chosen per track (`core.dpm.scale`; with an RGB
        model, or without depth, the depth-free search covers every scale anyway).
    min_confidence : parts less confident than this are reported MISSING.
    unary : the photograph network as a colour unary of the part model's tree
        (`core.dpm.net_unary.NetUnary`); None = the model's HOG filters alone.
    """

    MIN_CONFIDENCE = 0.0  # the default of `min_confidence` (and of the detector node's)

    def __init__(self, model: PartModel, *, search: SearchConfig | None = None,
                 scale: ScaleConfig | None = None, min_confidence: float = MIN_CONFIDENCE,
                 unary: NetUnary | None = None) -> None:
        self.model = model
        self.detector = Detector(model, search, unary)
        self.person_scale = PersonScale(scale)
        self.last_flags: tuple[str, ...] = ()
        self._previous: tuple[NDArray[np.float64], float] | None = None  # parts' uv, stamp
        self.configure(search=search, scale=scale, min_confidence=min_confidence)

    def configure(self, *, search: SearchConfig | None = None, scale: ScaleConfig | None = None,
                  min_confidence: float = MIN_CONFIDENCE) -> None:
        """New settings (as in the constructor), used from the next frame on (new person scale
        settings start the choice of scale anew)."""
        if not 0.0 <= min_confidence <= 1.0:
            raise ValueError(f'min_confidence must be in [0, 1], got {min_confidence}')
        self.detector.config = search or SearchConfig()
        if (scale or ScaleConfig()) != self.person_scale.config:
            self.person_scale = PersonScale(scale)
        self.min_confidence = min_confidence

    def spawn(self) -> DetectorStage:
        """A new stage with this one's settings as they are now and the same model, knowing
        nobody yet: another person's (`core.people`)."""
        return DetectorStage(self.model, search=self.detector.config,
                             scale=self.person_scale.config, min_confidence=self.min_confidence,
                             unary=self.detector.unary)

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.part_names

    def reset(self) -> None:
        """Forget the person (the next frame starts a new track)."""
        self.person_scale.reset()
        self._previous = None

    def _prior(self, stamp_s: float | None) -> NDArray[np.float64] | None:
        """The previous frame's parts when they are recent enough to guide this frame's arms."""
        if stamp_s is None or self._previous is None:
            return None
        uv, last = self._previous
        return uv if 0.0 < stamp_s - last <= PRIOR_MAX_GAP_S else None

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Run on a synthetic frame (`warm_up_frame`) twice, the second time guided by the
        first (`SearchConfig.arm_prior`), so the kernels are compiled and loaded, then forget
        it."""
        color, depth, mask = warm_up_frame(intrinsics)
        # and on read-only views, as a node's frames are (arrays on a message's buffer): each
        # kernel's signature for them loaded in this process now, not at the first frame
        for c, d, m in ((color, depth, mask),
                        (_read_only(color), _read_only(depth), _read_only(mask))):
            for stamp_s in (0.0, 1.0 / 30.0):
                self.step(c, d, intrinsics, mask=m, stamp_s=stamp_s)
            self.reset()

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None, *, mask: NDArray[np.bool_] | None = None,
             stamp_s: float | None = None, blanked: bool = False,
             occluder: NDArray[np.bool_] | None = None,
             photo: NDArray[np.uint8] | None = None) -> JointSet:
        """The detected parts of one frame (all MISSING when there is no person to search).

        `blanked`: colour and depth are already blanked outside `mask` (as `ForegroundStage`
        returns them), so the detector need not blank them again. `occluder`: the pixels of
        nearer people, where a part may lie hidden (`SearchConfig.occluded_quantile`).
        `photo`: the camera's colour, not blanked (for the photograph network:
        `Detector.detect`).

        `stamp_s` (the frame's time, seconds) tells the person's scale when a new track starts
        (`core.dpm.scale.PersonScale`: the person unseen for a while); without it, only
        `reset` does. While the scale is undecided (every factor searched), each part is the
        medoid of the factors' poses (`medoid_parts`). With it, the previous frame's parts,
        if at most `PRIOR_MAX_GAP_S` old, guide this frame's arms (`SearchConfig.arm_prior`).
        `last_flags` tells why a result is doubtful ('no_person', 'low_score', 'no_depth').
        ValueError when `intrinsics` are for another image size.
        """
        color = np.asarray(color)
        if intrinsics is not None:
            intrinsics.check_size(color.shape)
        scaled = depth_m is not None and self.model.channels == 'rgbd'
        factors = self.person_scale.factors(stamp_s) if scaled else (1.0,)
        prior = self._prior(stamp_s)
        found = {f: self.detector.detect(color, depth_m, mask=mask, intrinsics=intrinsics,
                                         scale=f, blanked=blanked, prior=prior,
                                         occluder=occluder, photo=photo)
                 for f in factors}
        if not any(found.values()):
            self.last_flags = ('no_person',)
            self._previous = None
            return JointSet.missing(self.names)
        if scaled:
            chosen = self.person_scale.update(
                {f: poses[0].rank if poses else math.nan for f, poses in found.items()})
            pose = found[chosen][0]
            poses = [v[0] for v in found.values()
                     if v and np.logical_and.reduce(np.isfinite(v[0].uv), axis=None)]
            if len(poses) >= 3:
                # the person's scale still undecided (a track's first frames): each part where
                # the poses found at the factors agree most, not where the leading one put it
                pose = replace(pose, uv=medoid_parts([p.uv for p in poses]))
        else:
            pose = found[1.0][0]
        self.last_flags = pose.flags
        conf = pose.confidence.astype(np.float32)
        src = np.where(conf >= self.min_confidence, cj.DETECTED, cj.MISSING).astype(np.uint8)
        # a part the model places beyond the image's edge (its filter hanging over the border)
        # is put on the edge: a detection is a pixel of the image
        h, w = color.shape[:2]
        # np.clip's values, without its Python wrapper
        on_image = np.minimum(np.maximum(pose.uv, 0.0), _image_max(w, h))
        uv = np.where(src[:, None] == cj.DETECTED, on_image, np.nan)
        self._previous = None if stamp_s is None else (uv, float(stamp_s))
        xyz = np.full((len(self.names), 3), np.nan)
        if depth_m is not None and intrinsics is not None:
            z = lift_parts(self.model, depth_m, uv, intrinsics, mask)
            if self.model.refiner is not None:
                # where the joints really are, learned (`core.refine`); still on the image
                uv, z = self.model.refiner.apply(self.names, self.model.parents, uv, z, conf,
                                                 depth_m, intrinsics, mask)
            xyz = backproject(uv, z, intrinsics)
        return JointSet(self.names, uv, xyz, confidence=np.where(src == cj.DETECTED, conf, 0),
                        source=src, score=float(pose.score))
