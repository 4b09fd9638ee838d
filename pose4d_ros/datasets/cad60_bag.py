"""CAD-60 directory (real or synthetic) -> rosbag2 with the topics of a Kinect driver.

Topics, all stamped with the frame time (`cad60.read_frames`: 30 fps, videos one second apart)
and recorded at that time:

- `/camera/color/image_raw` (sensor_msgs/Image, rgb8)
- `/camera/depth/image_raw` (sensor_msgs/Image, 16UC1 millimetres, registered to colour)
- `/camera/color/camera_info` (the OpenNI perspective intrinsics, optical frame)
- `/cad60/skeleton` (pose4d_msgs/JointArray: the dataset's 15 joints as ground truth: u, v in
  the colour image by the chosen projection model, 3-D position in the optical frame, the
  file's confidence; a joint with confidence 0 is MISSING)
- `/cad60/skeletons` (pose4d_msgs/SkeletonArray) only when the set has several-person videos
  (`pose4d synth --people N`, see `cad60`): every person's ground truth, person k with
  `track_id` k, person 1 (the one on `/cad60/skeleton`) first; a single-person video of such
  a set gets an empty array (so that every frame has one).
- `/cad60/mask` (sensor_msgs/Image, mono8, 255 = person) when the set has `Mask_<k>.png`
  (the synthetic sets do): the ground truth of the foreground stage (every person's pixels).

The bag is written atomically (see `bag.BagWriter`), mcap with zstd chunk compression unless
asked otherwise. `read_frames` reads such a bag (or any bag with these topics) back as frames.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pose4d_ros.core.camera import Intrinsics, depth_to_millimetres
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.sync import StampSync
from pose4d_ros.datasets import bag, cad60
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.wire import (
    color_from_msg,
    depth_from_msg,
    image_to_array,
    intrinsics_from_msg,
    joints_from_msg,
    skeletons_from_msg,
    stamp_to_ns,
)

COLOR_TOPIC = '/camera/color/image_raw'
DEPTH_TOPIC = '/camera/depth/image_raw'
INFO_TOPIC = '/camera/color/camera_info'
SKELETON_TOPIC = '/cad60/skeleton'
SKELETONS_TOPIC = '/cad60/skeletons'
MASK_TOPIC = '/cad60/mask'
FRAME_ID = 'camera_color_optical_frame'
CAMERA_TOPICS = (COLOR_TOPIC, DEPTH_TOPIC, INFO_TOPIC)


@dataclass(frozen=True)
class ConversionResult:
    path: Path
    frames: int
    videos: int
    counts: dict[str, int]
    duration_s: float


def convert(root: str | Path, out: str | Path, *, storage: str = 'mcap', compress: bool = True,
            projection: str = 'perspective', t0_s: float = cad60.T0_S,
            videos: Sequence[str] | None = None, max_frames: int | None = None,
            frame_id: str = FRAME_ID, progress: Callable[[int], Any] | None = None
            ) -> ConversionResult:
    """Write the videos of a CAD-60 directory to a rosbag2 at `out`.

    Parameters
    ----------
    root : a person directory (`dataN/`) or a directory of them.
    out : the new bag directory (must not exist).
    projection : 'perspective' (default) or 'affine' (the dataset README's fit) for the
        ground-truth pixels; camera_info always carries the perspective model.
    videos : only these video ids (all if None).
    max_frames : at most this many frames per video.
    progress : called with the number of frames written so far, after each frame.
    """
    types = bag.typestore().types
    frames, seen, first_ns, last_ns = 0, set(), None, None
    chosen = [v for v in cad60.list_videos(root) if videos is None or v.video_id in videos]
    several = any(len(v.skeleton_paths()) > 1 for v in chosen)
    with bag.BagWriter(out, storage=storage, compress=compress) as writer:
        for topic, msgtype in ((COLOR_TOPIC, 'sensor_msgs/msg/Image'),
                               (DEPTH_TOPIC, 'sensor_msgs/msg/Image'),
                               (INFO_TOPIC, 'sensor_msgs/msg/CameraInfo'),
                               (SKELETON_TOPIC, 'pose4d_msgs/msg/JointArray')):
            writer.add_topic(topic, msgtype)
        if several:
            writer.add_topic(SKELETONS_TOPIC, 'pose4d_msgs/msg/SkeletonArray')
        for frame in cad60.read_frames(root, videos=videos, max_frames=max_frames,
                                       projection=projection, t0_s=t0_s):
            stamp_ns = frame.stamp_ns
            header = _header(types, stamp_ns, frame_id)
            writer.write(COLOR_TOPIC, stamp_ns, _image(types, header, frame.color, 'rgb8'))
            writer.write(DEPTH_TOPIC, stamp_ns,
                         _image(types, header, depth_to_millimetres(frame.depth_m), '16UC1'))
            writer.write(INFO_TOPIC, stamp_ns, _camera_info(types, header, frame.intrinsics))
            writer.write(SKELETON_TOPIC, stamp_ns, _joint_array(types, header, frame.truth))
            if several:
                writer.write(SKELETONS_TOPIC, stamp_ns, types['pose4d_msgs/msg/SkeletonArray'](
                    header=header,
                    skeletons=[_joint_array(types, header, p) for p in frame.people]))
            if frame.mask is not None:
                if MASK_TOPIC not in writer.counts:
                    writer.add_topic(MASK_TOPIC, 'sensor_msgs/msg/Image')
                writer.write(MASK_TOPIC, stamp_ns, _image(
                    types, header, frame.mask.astype(np.uint8) * 255, 'mono8'))
            frames += 1
            seen.add(frame.video)
            first_ns = stamp_ns if first_ns is None else first_ns
            last_ns = stamp_ns
            if progress is not None:
                progress(frames)
        counts = dict(writer.counts)
    duration_s = (last_ns - first_ns) * 1e-9 if frames else 0.0
    return ConversionResult(Path(out), frames, len(seen), counts, duration_s)


def _header(types: dict, stamp_ns: int, frame_id: str) -> Any:
    return types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=stamp_ns // 10**9,
                                                   nanosec=stamp_ns % 10**9),
        frame_id=frame_id)


def _image(types: dict, header: Any, img: np.ndarray, encoding: str) -> Any:
    img = np.ascontiguousarray(img)
    channels = img.shape[2] if img.ndim == 3 else 1
    return types['sensor_msgs/msg/Image'](
        header=header, height=img.shape[0], width=img.shape[1], encoding=encoding,
        is_bigendian=0, step=img.shape[1] * channels * img.dtype.itemsize,
        data=img.view(np.uint8).reshape(-1))


def _camera_info(types: dict, header: Any, intr: Intrinsics) -> Any:
    fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy
    roi = types['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0,
                                                     do_rectify=False)
    return types['sensor_msgs/msg/CameraInfo'](
        header=header, height=intr.height, width=intr.width, distortion_model='plumb_bob',
        d=np.zeros(5), k=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64),
        r=np.eye(3).ravel(), p=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], np.float64),
        binning_x=0, binning_y=0, roi=roi)


def _joint_array(types: dict, header: Any, joints: JointSet) -> Any:
    Joint, Point = types['pose4d_msgs/msg/Joint'], types['geometry_msgs/msg/Point']
    out = [Joint(name=name, u=float(joints.uv[j, 0]), v=float(joints.uv[j, 1]),
                 position=Point(x=float(joints.xyz[j, 0]), y=float(joints.xyz[j, 1]),
                                z=float(joints.xyz[j, 2])),
                 confidence=float(joints.confidence[j]), source=int(joints.source[j]),
                 position_covariance=joints.covariance[j].reshape(9))
           for j, name in enumerate(joints.names)]
    return types['pose4d_msgs/msg/JointArray'](header=header, track_id=int(joints.track_id),
                                               score=float(joints.score), joints=out)


def read_frames(path: str | Path) -> Iterator[Frame]:
    """The RGB-D frames of a bag in stamp order: colour, depth and camera_info of the same
    header stamp (`core.sync.StampSync`), with the ground truth (`/cad60/skeleton`), every
    person's ground truth (`/cad60/skeletons`, into `Frame.people`) and the mask (`/cad60/mask`)
    of that stamp when the bag has those topics.

    Raises ValueError naming the bag and topic when a needed topic is missing; a frame without
    a message of every topic at its stamp is skipped.
    """
    infos = bag.topics(path)
    for topic in CAMERA_TOPICS:
        if topic not in infos:
            raise ValueError(f'{path}: no {topic} topic (has {", ".join(sorted(infos))})')
    topics = [COLOR_TOPIC, DEPTH_TOPIC, INFO_TOPIC]
    topics += [t for t in (SKELETON_TOPIC, SKELETONS_TOPIC, MASK_TOPIC) if t in infos]
    stream = {t: k for k, t in enumerate(topics)}
    sync = StampSync(len(topics))
    for m in bag.read_messages(path, topics):
        msg = bag.deserialize(m)
        for stamp, items in sync.push(stream[m.topic], stamp_to_ns(msg.header.stamp), msg):
            got = dict(zip(topics, items, strict=True))
            yield Frame(stamp, color_from_msg(got[COLOR_TOPIC]),
                        depth_from_msg(got[DEPTH_TOPIC]), intrinsics_from_msg(got[INFO_TOPIC]),
                        joints_from_msg(got[SKELETON_TOPIC]) if SKELETON_TOPIC in got else None,
                        image_to_array(got[MASK_TOPIC]) > 127 if MASK_TOPIC in got else None,
                        key=f'{path}@{stamp}',
                        people=skeletons_from_msg(got[SKELETONS_TOPIC])
                        if SKELETONS_TOPIC in got else ())
