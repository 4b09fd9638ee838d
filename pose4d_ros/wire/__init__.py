"""The wire format: our messages, and the ROS messages we read and write, as arrays and back.

What crosses a topic or lies in a bag is a message: an rclpy object in a node, a rosbags object
in a bag reader, or the serialised bytes of either (little-endian CDR, as Fast DDS carries them
and rosbag2 stores them). This package is the one place where those become the core's arrays
(`core.joints.JointSet`, images, `core.camera.Intrinsics`, nanoseconds) and where arrays become
bytes. It imports numpy, OpenCV and `core` only: no rclpy, no message package, no rosbags
(a test checks it), so the nodes, the bag readers and the offline tools share it. One module
a job:

- `pixels`: an Image's pixel buffer <-> an array, per encoding (`ENCODINGS`, `decode`,
  `as_encoding`);
- `msgs`: message objects (rclpy's or rosbags', read by their fields) -> arrays
  (`color_from_msg`, `depth_from_msg`, `image_to_array`, the compressed images',
  `intrinsics_from_msg`, `joints_from_msg`, `skeletons_from_msg`, `stamp_to_ns`);
- `cdr`: serialised bytes, read and written side by side (`cdr_header`, `image_from_cdr`,
  `joints_from_cdr`,
  `skeletons_from_cdr`; `joints_to_cdr`, `skeletons_to_cdr`, `image_to_cdr`, `tf_to_cdr`, whose
  header is any object with `stamp.sec`, `stamp.nanosec` and `frame_id`);
- `warm`: its numba kernels compiled before a node's first frame (`warm_up`);
- `hri`: the ROS4HRI (REP 155) body messages' bytes (`ids_list_to_cdr`, `skeleton2d_to_cdr`,
  `roi_to_cdr`), from `core.hri`'s values.

The rclpy message objects a node publishes (Image, CameraInfo, JointArray, markers, clouds, a
stamp from nanoseconds) are built in `nodes/convert.py`: they need rclpy's message classes.
"""

from pose4d_ros.wire.cdr import (
    CdrImage,
    HeaderLike,
    cdr_header,
    image_from_cdr,
    image_to_cdr,
    joint_frame,
    joints_from_cdr,
    joints_to_cdr,
    skeletons_from_cdr,
    skeletons_to_cdr,
    tf_to_cdr,
)
from pose4d_ros.wire.hri import ids_list_to_cdr, roi_to_cdr, skeleton2d_to_cdr
from pose4d_ros.wire.msgs import (
    color_from_compressed,
    color_from_msg,
    depth_from_compressed,
    depth_from_msg,
    image_to_array,
    intrinsics_from_msg,
    is_compressed_depth,
    joints_from_msg,
    skeletons_from_msg,
    stamp_to_ns,
)
from pose4d_ros.wire.pixels import ENCODINGS, as_encoding, decode
from pose4d_ros.wire.warm import warm_up

__all__ = ['CdrImage', 'ENCODINGS', 'as_encoding', 'cdr_header', 'color_from_compressed',
           'color_from_msg', 'decode', 'depth_from_compressed', 'depth_from_msg', 'HeaderLike',
           'ids_list_to_cdr', 'image_from_cdr', 'image_to_array', 'image_to_cdr',
           'intrinsics_from_msg', 'is_compressed_depth', 'joint_frame', 'joints_from_cdr',
           'joints_from_msg', 'joints_to_cdr', 'roi_to_cdr', 'skeleton2d_to_cdr',
           'skeletons_from_cdr', 'skeletons_from_msg', 'skeletons_to_cdr', 'stamp_to_ns',
           'tf_to_cdr', 'warm_up']
