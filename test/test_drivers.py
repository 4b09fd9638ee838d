"""The camera drivers robots carry, as the `pipeline` node meets them: each driver's topic
names (remapped as the README says), colour and depth encodings, size and QoS, with a rendered
640x480 person; the node must put out the skeleton, its head on the person's."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from harness import start
from helpers import standing_pose

from pose4d_ros.core.camera import cad60_intrinsics, project
from pose4d_ros.synth import render as synth
from pose4d_ros.synth import scene as synth_scene

INTR = cad60_intrinsics(640, 480)


@dataclass(frozen=True)
class Driver:
    """What a driver publishes: topics, encodings and the reliability of its image topics."""

    color: str
    depth: str
    info: str
    color_encoding: str
    reliable: bool


# The README's "Camera drivers" section gives the launch options behind each (aligned depth).
DRIVERS = {
    'realsense2_camera': Driver('/camera/camera/color/image_raw',
                                '/camera/camera/aligned_depth_to_color/image_raw',
                                '/camera/camera/color/camera_info', 'rgb8', True),
    'azure_kinect_ros_driver': Driver('/rgb/image_raw', '/depth_to_rgb/image_raw',
                                      '/rgb/camera_info', 'bgra8', True),
    'orbbec_camera': Driver('/camera/color/image_raw', '/camera/depth/image_raw',
                            '/camera/color/camera_info', 'rgb8', True),
    'depthai_ros_driver': Driver('/oak/rgb/image_raw', '/oak/stereo/image_raw',
                                 '/oak/rgb/camera_info', 'bgr8', False),
}
COLOUR_FROM_RGB = {'rgb8': None, 'bgr8': cv2.COLOR_RGB2BGR, 'bgra8': cv2.COLOR_RGB2BGRA}


@pytest.fixture(scope='module')
def person() -> synth.Rendered:
    rng = np.random.default_rng(5)
    body = synth.random_body(rng)
    scene = synth_scene.random_scene(rng, INTR, occluder_prob=0.0)
    return synth.render(standing_pose(z=2.6, arm=0.4), body, scene, INTR,
                        rng=np.random.default_rng(0))


@pytest.mark.parametrize('name', sorted(DRIVERS))
def test_the_pipeline_node_takes_the_driver_as_it_publishes(ros, person, tmp_path, name):
    from pose4d_msgs.msg import JointArray
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header

    from pose4d_ros.core.skeleton import SKELETON_14
    from pose4d_ros.datasets.utkinect import UTKINECT_JOINTS
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg, ns_to_stamp
    from pose4d_ros.wire import joints_from_msg

    driver = DRIVERS[name]
    remaps = {'camera/color/image_raw': driver.color, 'camera/depth/image_raw': driver.depth,
              'camera/color/camera_info': driver.info}
    node = start('pipeline', {'pipeline.publish_foreground': False}, log_dir=tmp_path,
                 remaps=remaps)
    try:
        image_qos = QoSProfile(depth=5, history=HistoryPolicy.KEEP_LAST, reliability=(
            ReliabilityPolicy.RELIABLE if driver.reliable else ReliabilityPolicy.BEST_EFFORT))
        color_pub = ros.node.create_publisher(Image, driver.color, image_qos)
        depth_pub = ros.node.create_publisher(Image, driver.depth, image_qos)
        info_pub = ros.node.create_publisher(CameraInfo, driver.info, image_qos)
        skeletons = ros.collect(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        for pub in (color_pub, depth_pub, info_pub):
            ros.wait_for_subscribers(pub, timeout=30.0)
        ros.wait_for_publishers('pose4d/skeleton', timeout=30.0)
        code = COLOUR_FROM_RGB[driver.color_encoding]
        color = person.rgb if code is None else cv2.cvtColor(person.rgb, code)
        header = Header(stamp=ns_to_stamp(10**18), frame_id=f'{name}_color_optical_frame')

        def send() -> None:
            color_pub.publish(array_to_image(color, driver.color_encoding, header))
            depth_pub.publish(array_to_image(person.depth_mm, '16UC1', header))
            info_pub.publish(intrinsics_to_msg(INTR, header))

        ros.send_until_answered(send, lambda: any(m.header == header for m in skeletons),
                                f'the skeleton from {name}\'s topics')
    finally:
        assert node.stop() == 0, node.output()
    skeleton = joints_from_msg(next(m for m in skeletons if m.header == header))
    assert skeleton.names == SKELETON_14
    head = project(person.joints, INTR)[UTKINECT_JOINTS.index('head')]
    k = SKELETON_14.index('head')
    assert np.linalg.norm(skeleton.uv[k] - head) < 15.0, (skeleton.uv[k], head)
    assert np.isfinite(skeleton.xyz[k]).all()
