"""Large camera frames over Fast DDS: VGA RGB-D published best effort reaches a node.

With Fast DDS's defaults, a 640x480 colour frame (0.9 MB) does not fit the 0.5 MB shared-memory
segment and goes over UDP in fragments, which a best-effort sample loses (most frames never
arrive). The project's profile (config/fastdds.xml, which conftest.py sets as the Makefile does)
gives the graph a shared-memory segment that holds them.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from harness import start

from pose4d_ros.core.camera import cad60_intrinsics
from pose4d_ros.core.warm_up import warm_up_frame


def test_the_project_profile_is_in_use() -> None:
    profile = Path(os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'])
    assert profile.is_file(), profile
    assert '<segment_size>' in profile.read_text()


@pytest.mark.parametrize('width,height', [(640, 480), (848, 480)])
def test_best_effort_vga_frames_reach_the_foreground_node(ros, tmp_path, width, height) -> None:
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header

    from pose4d_ros.core.camera import depth_to_millimetres
    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg, ns_to_stamp

    intr = cad60_intrinsics(width, height)
    color, depth, _ = warm_up_frame(intr)
    # as a camera driver publishes: best effort, keep last few
    camera_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT,
                            history=HistoryPolicy.KEEP_LAST)
    node = start('foreground', {}, log_dir=tmp_path)
    try:
        pubs = [ros.node.create_publisher(kind, topic, camera_qos) for kind, topic in (
            (Image, 'camera/color/image_raw'), (Image, 'camera/depth/image_raw'),
            (CameraInfo, 'camera/color/camera_info'))]
        masks = ros.collect(Image, 'pose4d/foreground/mask', qos.OUTPUT_QOS)
        # the masked colour wanted: the node reads the camera's colour (the largest frame) too
        colours = ros.collect(Image, 'pose4d/foreground/color', qos.OUTPUT_QOS)
        for pub in pubs:
            ros.wait_for_subscribers(pub)
        ros.wait_for_publishers('pose4d/foreground/mask')

        def send(k: int) -> Header:
            header = Header(stamp=ns_to_stamp(10**18 + k * 100_000_000), frame_id='cam')
            pubs[0].publish(array_to_image(color, 'rgb8', header))
            pubs[1].publish(array_to_image(depth_to_millimetres(depth), '16UC1', header))
            pubs[2].publish(intrinsics_to_msg(intr, header))
            return header

        # A best-effort reader drops what comes before it has matched the writer, and our side
        # may see the match first: send until one frame comes out, then count.
        for k in range(20):
            primer = send(k)
            if ros.wait(lambda h=primer: h in [m.header for m in masks], 1.0):
                break
        sent = []
        for k in range(20):  # 10 frames per second: the node keeps up even on a loaded machine
            sent.append(send(100 + k))
            ros.spin_for(0.1)
        ros.wait(lambda: all(h in [m.header for m in masks] and h in [m.header for m in colours]
                             for h in sent), 5.0)
    finally:
        assert node.stop() == 0, node.output()
    for name, out in (('masks', masks), ('masked colours', colours)):
        got = [h for h in sent if h in [m.header for m in out]]
        assert len(got) == len(sent), f'{len(got)} of {len(sent)} {width}x{height} {name}'
    assert (masks[-1].width, masks[-1].height) == (width, height)
