"""Arrays -> the rclpy message objects the nodes publish (after cv_bridge and image_geometry):
what needs the message classes, and only that.

- numpy -> `sensor_msgs/Image` (rows packed), `PointCloud2`, RViz markers;
- `core.camera.Intrinsics` -> `sensor_msgs/CameraInfo`;
- `core.joints.JointSet` -> `pose4d_msgs/JointArray`, several people's `SkeletonArray`;
- integer nanoseconds -> `builtin_interfaces/Time`; a type name -> its message class.

Reading messages (objects or bytes) into arrays, and writing arrays straight to a message's
serialised bytes (what the nodes publish on their busy topics), is `pose4d_ros.wire`.
"""

from __future__ import annotations

import array
import importlib
import sys

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point
from numpy.typing import NDArray
from pose4d_msgs.msg import Joint, JointArray, SkeletonArray
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.draw import person_rgb
from pose4d_ros.core.joints import DETECTED, INFERRED, MISSING, TRACKED, JointSet
from pose4d_ros.wire.pixels import as_encoding

__all__ = ['array_to_image', 'cloud_to_msg', 'intrinsics_to_msg', 'joints_to_msg',
           'message_type', 'ns_to_stamp', 'people_markers', 'skeleton_markers',
           'skeletons_to_msg']


def ns_to_stamp(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def array_to_image(img: NDArray, encoding: str, header: Header) -> Image:
    """An Image message holding `img` (a copy), rows packed (step = width x pixel size)."""
    img, channels = as_encoding(img, encoding)
    msg = Image(header=header, height=img.shape[0], width=img.shape[1], encoding=encoding,
                is_bigendian=int(sys.byteorder == 'big'),
                step=img.shape[1] * channels * img.dtype.itemsize)
    msg.data = array.array('B', img.tobytes())
    return msg


def intrinsics_to_msg(intr: Intrinsics, header: Header) -> CameraInfo:
    fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy
    return CameraInfo(
        header=header, width=intr.width, height=intr.height, distortion_model='plumb_bob',
        d=[0.0] * 5, k=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def joints_to_msg(joints: JointSet, header: Header) -> JointArray:
    msg = JointArray(header=header, track_id=int(joints.track_id), score=float(joints.score))
    out = []
    for i, name in enumerate(joints.names):
        x, y, z = (float(c) for c in joints.xyz[i])
        out.append(Joint(
            name=name, u=float(joints.uv[i, 0]), v=float(joints.uv[i, 1]),
            position=Point(x=x, y=y, z=z), confidence=float(joints.confidence[i]),
            source=int(joints.source[i]),
            position_covariance=joints.covariance[i].reshape(9).tolist()))
    msg.joints = out
    return msg


def message_type(name: str) -> type:
    """The rclpy message class of a type name like 'sensor_msgs/msg/Image'."""
    parts = name.split('/')
    if len(parts) != 3 or parts[1] != 'msg':
        raise ValueError(f'not a message type name: {name!r} (expected pkg/msg/Name)')
    try:
        module = importlib.import_module(f'{parts[0]}.msg')
        return getattr(module, parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f'message type {name} is not installed') from None


def cloud_to_msg(xyz: NDArray[np.floating], rgb: NDArray[np.uint8] | None,
                 header: Header) -> PointCloud2:
    """An unorganised PointCloud2 (x, y, z float32 metres [+ rgb packed as float32])."""
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
              for i, n in enumerate('xyz')]
    if rgb is None:
        data = xyz
    else:
        rgb = np.asarray(rgb, dtype=np.uint8).reshape(-1, 3)
        packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) \
            | rgb[:, 2].astype(np.uint32)
        fields.append(PointField(name='rgb', offset=12, datatype=PointField.FLOAT32, count=1))
        data = np.concatenate([xyz, packed.view(np.float32)[:, None]], axis=1)
    data = np.ascontiguousarray(data, dtype=np.float32)
    msg = PointCloud2(header=header, height=1, width=len(data), fields=fields,
                      is_bigendian=sys.byteorder == 'big', point_step=data.shape[1] * 4,
                      row_step=data.shape[1] * 4 * len(data), is_dense=True)
    msg.data = array.array('B', data.tobytes())
    return msg


# RViz colours of joint sources: detected green, tracked blue, inferred orange, missing grey.
_SOURCE_RGBA = {DETECTED: (0.1, 0.85, 0.2, 1.0), TRACKED: (0.2, 0.5, 1.0, 1.0),
                INFERRED: (1.0, 0.55, 0.0, 1.0), MISSING: (0.5, 0.5, 0.5, 0.4)}


def skeleton_markers(joints: JointSet, bones: list[tuple[int, int]], header: Header,
                     *, namespace: str = 'pose4d', radius_m: float = 0.04,
                     lifetime_s: float = 0.5,
                     tint: tuple[float, float, float] | None = None) -> MarkerArray:
    """Spheres for the joints and lines for the bones, coloured by source, for RViz.

    Joints without a 3-D position are left out; a bone is drawn when both ends have one, in
    the colour of its less certain end (inferred over tracked over detected), or in `tint`
    (the person's colour, `people_markers`).
    """
    lifetime = Duration(sec=int(lifetime_s), nanosec=int((lifetime_s % 1) * 1e9))
    spheres = Marker(header=header, ns=f'{namespace}/joints', id=0,
                     type=Marker.SPHERE_LIST, action=Marker.ADD, lifetime=lifetime)
    spheres.pose.orientation.w = 1.0
    spheres.scale.x = spheres.scale.y = spheres.scale.z = radius_m
    lines = Marker(header=header, ns=f'{namespace}/bones', id=1, type=Marker.LINE_LIST,
                   action=Marker.ADD, lifetime=lifetime)
    lines.pose.orientation.w = 1.0
    lines.scale.x = radius_m / 3
    valid = np.isfinite(joints.xyz).all(axis=1)

    def point(i: int) -> Point:
        x, y, z = (float(c) for c in joints.xyz[i])
        return Point(x=x, y=y, z=z)

    def color(src: int) -> ColorRGBA:
        r, g, b, a = _SOURCE_RGBA[int(src)]
        return ColorRGBA(r=r, g=g, b=b, a=a)

    for i in np.flatnonzero(valid):
        spheres.points.append(point(int(i)))
        spheres.colors.append(color(joints.source[i]))
    rank = {DETECTED: 0, TRACKED: 1, INFERRED: 2, MISSING: 3}
    for a, b in bones:
        if valid[a] and valid[b]:
            worst = max(joints.source[a], joints.source[b], key=lambda s: rank[int(s)])
            lines.points.extend([point(a), point(b)])
            c = color(worst) if tint is None else ColorRGBA(r=tint[0], g=tint[1], b=tint[2],
                                                            a=1.0)
            lines.colors.extend([c, c])
    return MarkerArray(markers=[spheres, lines])


def people_markers(people: list[JointSet], bones: list[tuple[int, int]], header: Header, *,
                   lifetime_s: float = 0.5) -> MarkerArray:
    """`skeleton_markers` of every person, each in its namespace `pose4d/<track_id>` with its
    bones in its id's colour (`core.draw.person_rgb`, as in the demo's overlays)."""
    out = MarkerArray()
    for joints in people:
        tid = int(joints.track_id)
        out.markers.extend(skeleton_markers(
            joints, bones, header, namespace=f'pose4d/{tid}', lifetime_s=lifetime_s,
            tint=person_rgb(tid)).markers)
    return out


def skeletons_to_msg(people: list[JointSet], header: Header) -> SkeletonArray:
    """Every person of a frame as a SkeletonArray (each JointArray with the same header)."""
    return SkeletonArray(header=header, skeletons=[joints_to_msg(j, header) for j in people])
