"""CAD-60 directory (real or synthetic) -> rosbag2 with the topics of a Kinect driver.

Topics, all stamped with the frame time (30 fps from `t0`; videos follow each other with a
one-second gap) and recorded at that time:

- `/camera/color/image_raw` (sensor_msgs/Image, rgb8)
- `/camera/depth/image_raw` (sensor_msgs/Image, 16UC1 millimetres, registered to colour)
- `/camera/color/camera_info` (the OpenNI perspective intrinsics, optical frame)
- `/cad60/skeleton` (pose4d_msgs/JointArray: the dataset's 15 joints as ground truth: u, v in
  the colour image by the chosen projection model, 3-D position in the optical frame, the
  file's confidence; a joint with confidence 0 is MISSING)
- `/cad60/mask` (sensor_msgs/Image, mono8, 255 = person) when the set has `Mask_<k>.png`
  (the synthetic sets do): the ground truth of the foreground stage.

The bag is written atomically (see `bag.BagWriter`), mcap with zstd chunk compression unless
asked otherwise.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import Intrinsics, cad60_intrinsics, depth_to_metres
from pose4d_ros.core.skeleton import CAD60_JOINTS
from pose4d_ros.datasets import bag, cad60
from pose4d_ros.datasets.image_codec import decode

COLOR_TOPIC = '/camera/color/image_raw'
DEPTH_TOPIC = '/camera/depth/image_raw'
INFO_TOPIC = '/camera/color/camera_info'
SKELETON_TOPIC = '/cad60/skeleton'
MASK_TOPIC = '/cad60/mask'
FRAME_ID = 'camera_color_optical_frame'
FRAME_PERIOD_NS = 1_000_000_000 // 30 + 1  # 33.333... ms, rounded up so stamps never repeat
VIDEO_GAP_NS = 1_000_000_000


@dataclass(frozen=True)
class ConversionResult:
    path: Path
    frames: int
    videos: int
    counts: dict[str, int]
    duration_s: float


def convert(root: str | Path, out: str | Path, *, storage: str = 'mcap', compress: bool = True,
            projection: str = 'perspective', t0_s: float = 1_700_000_000.0,
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
    if projection not in ('perspective', 'affine'):
        raise ValueError(f"projection must be 'perspective' or 'affine', got {projection!r}")
    selected = cad60.list_videos(root)
    if videos is not None:
        unknown = set(videos) - {v.video_id for v in selected}
        if unknown:
            raise ValueError(f'{root}: no video(s) {", ".join(sorted(unknown))}')
        selected = [v for v in selected if v.video_id in set(videos)]
    store = bag.typestore()
    types = store.types
    intr = cad60_intrinsics()
    stamp_ns = int(round(t0_s * 1e9))
    frames = 0
    with bag.BagWriter(out, storage=storage, compress=compress) as writer:
        for topic, msgtype in ((COLOR_TOPIC, 'sensor_msgs/msg/Image'),
                               (DEPTH_TOPIC, 'sensor_msgs/msg/Image'),
                               (INFO_TOPIC, 'sensor_msgs/msg/CameraInfo'),
                               (SKELETON_TOPIC, 'pose4d_msgs/msg/JointArray')):
            writer.add_topic(topic, msgtype)
        has_mask = False
        first_ns = stamp_ns
        for video in selected:
            skeleton = cad60.read_skeleton(video.skeleton_path)
            pixels = skeleton.pixels(intr, model=projection)
            optical = skeleton.joints_optical()
            with_mask = cad60.frame_paths(video.frame_dir, int(skeleton.frames[0]))[2].is_file() \
                if len(skeleton) else False
            if with_mask and not has_mask:
                writer.add_topic(MASK_TOPIC, 'sensor_msgs/msg/Image')
                has_mask = True
            for i, frame in enumerate(cad60.iter_frames(video, skeleton=skeleton,
                                                        with_mask=with_mask)):
                if max_frames is not None and i >= max_frames:
                    break
                if i:
                    stamp_ns += FRAME_PERIOD_NS * int(frame.frame - skeleton.frames[i - 1])
                header = _header(types, stamp_ns, frame_id)
                writer.write(COLOR_TOPIC, stamp_ns, _image(types, header, frame.rgb, 'rgb8'))
                writer.write(DEPTH_TOPIC, stamp_ns,
                             _image(types, header, frame.depth_mm, '16UC1'))
                writer.write(INFO_TOPIC, stamp_ns, _camera_info(types, header, intr))
                writer.write(SKELETON_TOPIC, stamp_ns, _ground_truth(
                    types, header, pixels[i], optical[i], frame.joint_conf))
                if frame.mask is not None:
                    writer.write(MASK_TOPIC, stamp_ns, _image(
                        types, header, frame.mask.astype(np.uint8) * 255, 'mono8'))
                frames += 1
                if progress is not None:
                    progress(frames)
            stamp_ns += VIDEO_GAP_NS
        counts = dict(writer.counts)
    last_ns = stamp_ns - VIDEO_GAP_NS if selected else first_ns
    return ConversionResult(Path(out), frames, len(selected), counts,
                            max(last_ns - first_ns, 0) * 1e-9)


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


def _ground_truth(types: dict, header: Any, uv: np.ndarray, xyz: np.ndarray,
                  conf: np.ndarray) -> Any:
    Joint, Point = types['pose4d_msgs/msg/Joint'], types['geometry_msgs/msg/Point']
    joints = [
        Joint(name=name, u=float(uv[j, 0]), v=float(uv[j, 1]),
              position=Point(x=float(xyz[j, 0]), y=float(xyz[j, 1]), z=float(xyz[j, 2])),
              confidence=float(conf[j]),
              source=cj.DETECTED if conf[j] > 0 else cj.MISSING,
              position_covariance=np.zeros(9))
        for j, name in enumerate(CAD60_JOINTS)]
    return types['pose4d_msgs/msg/JointArray'](header=header, track_id=1, score=1.0,
                                               joints=joints)


@dataclass(frozen=True)
class BagFrame:
    """One RGB-D frame of a bag with its ground truth (what `read_frames` yields).

    Attributes
    ----------
    stamp_ns : header stamp of the colour image.
    color : (H, W, 3) uint8 RGB.
    depth_m : (H, W) float32 metres, NaN = no reading.
    intrinsics : from the frame's camera_info.
    truth : the ground-truth joints (`/cad60/skeleton`), or None if the bag has none.
    mask : (H, W) bool ground-truth person mask (`/cad60/mask`), or None.
    """

    stamp_ns: int
    color: np.ndarray
    depth_m: np.ndarray
    intrinsics: Intrinsics
    truth: cj.JointSet | None
    mask: np.ndarray | None


def read_frames(path: str | Path, *, color_topic: str = COLOR_TOPIC,
                depth_topic: str = DEPTH_TOPIC, info_topic: str = INFO_TOPIC
                ) -> Iterator[BagFrame]:
    """The RGB-D frames of a bag in stamp order: colour, depth and camera_info of the same
    header stamp, with the ground truth and mask of that stamp when the bag has them.

    Raises ValueError naming the bag and topic when a needed topic is missing; frames whose
    colour has no depth or camera_info of the same stamp are skipped.
    """
    infos = bag.topics(path)
    for topic in (color_topic, depth_topic, info_topic):
        if topic not in infos:
            raise ValueError(f'{path}: no {topic} topic (has {", ".join(sorted(infos))})')
    topics = [color_topic, depth_topic, info_topic]
    topics += [t for t in (SKELETON_TOPIC, MASK_TOPIC) if t in infos]
    pending: dict[int, dict[str, Any]] = {}
    for m in bag.read_messages(path, topics):
        msg = bag.deserialize(m)
        stamp = bag.stamp_ns(msg)
        pending.setdefault(stamp, {})[m.topic] = msg
        ready = [s for s, got in pending.items()
                 if s < stamp and all(t in got for t in (color_topic, depth_topic, info_topic))]
        for s in sorted(ready):
            yield _frame(s, pending.pop(s), color_topic, depth_topic, info_topic)
        for s in [s for s in pending if s < stamp - 10**9]:  # incomplete and old: skip
            del pending[s]
    for s in sorted(pending):
        got = pending[s]
        if all(t in got for t in (color_topic, depth_topic, info_topic)):
            yield _frame(s, got, color_topic, depth_topic, info_topic)


def _frame(stamp: int, got: dict[str, Any], color_topic: str, depth_topic: str,
           info_topic: str) -> BagFrame:
    color = _pixels(got[color_topic])
    if got[color_topic].encoding == 'bgr8':
        color = color[:, :, ::-1]
    depth = depth_to_metres(_pixels(got[depth_topic]))
    k = got[info_topic].k
    info = got[info_topic]
    intr = Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(info.width),
                      int(info.height))
    truth = bag.joint_set(got[SKELETON_TOPIC]) if SKELETON_TOPIC in got else None
    mask = _pixels(got[MASK_TOPIC]) > 127 if MASK_TOPIC in got else None
    return BagFrame(stamp, np.ascontiguousarray(color), depth, intr, truth, mask)


def _pixels(msg: Any) -> np.ndarray:
    return decode(msg.data, msg.height, msg.width, msg.step, msg.encoding, msg.is_bigendian)


def cad60_frames(root: str | Path, *, projection: str = 'perspective',
                 t0_s: float = 1_700_000_000.0, videos: Sequence[str] | None = None,
                 stride: int = 1) -> Iterator[BagFrame]:
    """The frames of a CAD-60 directory as `read_frames` gives them from its converted bag.

    Stamps follow `convert` (30 fps from `t0_s`, a one-second gap between videos), so a
    directory and its bag give the same frames, and a tracker sees each video as a new track.
    `stride` keeps every n-th frame of each video.
    """
    if stride < 1:
        raise ValueError(f'stride must be >= 1, got {stride}')
    selected = cad60.list_videos(root)
    if videos is not None:
        selected = [v for v in selected if v.video_id in set(videos)]
    intr = cad60_intrinsics()
    stamp_ns = int(round(t0_s * 1e9))
    for video in selected:
        skeleton = cad60.read_skeleton(video.skeleton_path)
        pixels = skeleton.pixels(intr, model=projection)
        optical = skeleton.joints_optical()
        with_mask = len(skeleton) > 0 and \
            cad60.frame_paths(video.frame_dir, int(skeleton.frames[0]))[2].is_file()
        for i, frame in enumerate(cad60.iter_frames(video, skeleton=skeleton,
                                                    with_mask=with_mask)):
            if i:
                stamp_ns += FRAME_PERIOD_NS * int(frame.frame - skeleton.frames[i - 1])
            if i % stride:
                continue
            conf = frame.joint_conf
            truth = cj.JointSet(CAD60_JOINTS, pixels[i], optical[i],
                                confidence=conf.astype(np.float32),
                                source=np.where(conf > 0, cj.DETECTED, cj.MISSING), track_id=1)
            yield BagFrame(stamp_ns, frame.rgb, depth_to_metres(frame.depth_mm), intr, truth,
                           frame.mask)
        stamp_ns += VIDEO_GAP_NS
