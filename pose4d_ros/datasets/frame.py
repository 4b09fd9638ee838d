"""The one frame type of every source (CAD-60 directory, rosbag2, LSPET): `Frame`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.joints import JointSet


@dataclass(frozen=True)
class Frame:
    """One frame of a source, with its ground truth when the source has one.

    Attributes
    ----------
    stamp_ns : capture time, nanoseconds: a bag's header stamp; a CAD-60 video's 30 fps clock
        (as `pose4d cad60-to-bag` stamps it: a one-second gap between videos, so a tracker sees
        each video as a new track); LSPET: one photo a second.
    color : (H, W, 3) uint8 RGB.
    depth_m : (H, W) float32 metres registered to `color`, NaN = no reading; None if the source
        has no depth (LSPET).
    intrinsics : the colour camera, None if unknown (LSPET).
    truth : the ground-truth joints in skeleton names (`core.skeleton`): pixels, 3-D positions
        in the optical frame (NaN where unknown), confidence > 0 where labelled (and, where the
        source says so, visible); None for a source without ground truth.
    mask : (H, W) bool ground-truth person mask (synthetic sets; in a several-person set the
        pixels of every person), else None.
    key : where the frame comes from (file, or bag@stamp), for messages.
    video : the video the frame belongs to ('' if unknown).
    people : every person's ground truth in a several-person source (a CAD-60 set with
        `<id>_p<k>.txt` files, a bag with `/cad60/skeletons`), person k with `track_id` = k,
        person 1 first (`truth` is person 1's); empty for a single-person source.
    """

    stamp_ns: int
    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32] | None
    intrinsics: Intrinsics | None
    truth: JointSet | None
    mask: NDArray[np.bool_] | None = None
    key: str = ''
    video: str = ''
    people: tuple[JointSet, ...] = ()
