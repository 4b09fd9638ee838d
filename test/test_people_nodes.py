"""Two people through every graph: the `pipeline` node, the per-stage graph (foreground,
detector, tracker, ik) and those four nodes composed in one process, fed rendered frames of
two people walking sideways past each other at different depths. Checked: one SkeletonArray
per frame on /pose4d/skeletons with both people once their tracks are confirmed, ids 1 and 2
that stay with their person (each id's head on that person's head), /pose4d/skeleton = the
primary person (id 1), and an empty SkeletonArray when nobody is in view.
"""

from __future__ import annotations

import numpy as np
import pytest
from harness import start
from helpers import INTR, standing_pose

from pose4d_ros.core.camera import project

FRAMES = 14
HEAD = 3  # UTKinect joint index of the head


def _frames():
    """Two empty frames, then rendered frames: person A at 2.4 m walking right, person B at
    3.4 m walking left, their heads' pixels; then one empty frame again."""
    from pose4d_ros.synth import render

    rng = np.random.default_rng(5)
    bodies = [render.random_body(np.random.default_rng(k)) for k in range(2)]
    empty = (np.zeros((INTR.height, INTR.width, 3), np.uint8),
             np.zeros((INTR.height, INTR.width), np.uint16), [])
    out = [empty, empty]
    for k in range(FRAMES):
        layers, heads = [], []
        for p, (x, z, v) in enumerate(((-0.75, 2.4, 0.01), (0.75, 3.4, -0.01))):
            pose = standing_pose(z=z, cam_height=1.0, arm=0.3)
            pose[:, 0] += x + v * k
            r = render.render(pose, bodies[p], None, INTR, rng=rng, kinect_noise=False)
            layers.append(r)
            heads.append(project(r.joints, INTR)[HEAD])
        d0, d1 = (r.depth_mm.astype(np.int64) for r in layers)
        first = (d0 > 0) & ((d1 == 0) | (d0 <= d1))
        out.append((np.where(first[..., None], layers[0].rgb, layers[1].rgb),
                    np.where(first, d0, d1).astype(np.uint16), heads))
    out.append(empty)
    return out


@pytest.fixture(scope='module')
def frames():
    return _frames()


@pytest.mark.parametrize('graph', ['pipeline', 'stages', 'composed'])
def test_two_people_get_two_stable_ids(ros, tmp_path, frames, graph):
    from pose4d_msgs.msg import JointArray, SkeletonArray
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header

    from pose4d_ros.nodes import qos
    from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg, ns_to_stamp
    from pose4d_ros.wire import skeletons_from_msg

    exes = {'pipeline': ['pipeline'], 'composed': ['composed']}.get(
        graph, ['foreground', 'detector', 'tracker', 'ik'])
    nodes = [start(exe, log_dir=tmp_path) for exe in exes]
    try:
        pubs = (ros.node.create_publisher(Image, 'camera/color/image_raw', qos.OUTPUT_QOS),
                ros.node.create_publisher(Image, 'camera/depth/image_raw', qos.OUTPUT_QOS),
                ros.node.create_publisher(CameraInfo, 'camera/color/camera_info',
                                          qos.OUTPUT_QOS))
        everyone = ros.collect(SkeletonArray, 'pose4d/skeletons', qos.OUTPUT_QOS)
        primary = ros.collect(JointArray, 'pose4d/skeleton', qos.OUTPUT_QOS)
        for pub in pubs:
            ros.wait_for_subscribers(pub, timeout=60.0)
        ros.wait_for_publishers('pose4d/skeletons', timeout=60.0)
        if graph != 'pipeline':  # every stage connected to the next
            for topic, n in (('/pose4d/foreground/mask', 1), ('/pose4d/parts/people', 1),
                             ('/pose4d/parts/tracked/people', 1)):
                ros.spin_until(lambda t=topic, n=n: ros.node.count_subscribers(t) >= n, 60.0,
                               f'a subscriber on {topic}')
        headers = [Header(stamp=ns_to_stamp(10**18 + k * 33_333_334), frame_id='cam')
                   for k in range(len(frames))]
        for (rgb, depth, _), header in zip(frames, headers, strict=True):
            def send(rgb=rgb, depth=depth, header=header):
                pubs[0].publish(array_to_image(rgb, 'rgb8', header))
                pubs[1].publish(array_to_image(depth, '16UC1', header))
                pubs[2].publish(intrinsics_to_msg(INTR, header))
            ros.send_until_answered(send, lambda h=header: any(m.header == h for m in everyone),
                                    f'the frame at {header.stamp.nanosec} ns', timeout=5.0)
    finally:
        for node in nodes:
            assert node.stop() == 0, node.output()
    by_stamp = {}
    for m in everyone:
        by_stamp.setdefault(m.header.stamp.nanosec, m)
    singles = {}
    for m in primary:
        singles.setdefault(m.header.stamp.nanosec, m)
    owner: dict[int, int] = {}  # track id -> person (0: the near one, 1: the far one)
    for k, ((_, _, heads), header) in enumerate(zip(frames, headers, strict=True)):
        people = skeletons_from_msg(by_stamp[header.stamp.nanosec])
        if not heads and k < 2:  # nobody in view: an empty array, an empty primary skeleton
            assert people == () and singles[header.stamp.nanosec].track_id == 0
            continue
        if not heads:  # everyone just left: their tracks predicted, nothing detected
            assert sorted(p.track_id for p in people) == [1, 2]
            assert all((p.source != 0).all() for p in people)
            continue
        if k < 6:  # the tracks' first frames
            continue
        assert sorted(p.track_id for p in people) == [1, 2], (k, [p.track_id for p in people])
        for p in people:
            head = p.uv[p.get('head')]
            person = int(np.argmin([np.linalg.norm(head - h) for h in heads]))
            assert np.linalg.norm(head - heads[person]) < 15, (k, p.track_id, head, heads)
            assert owner.setdefault(p.track_id, person) == person, f'id {p.track_id} swapped'
        assert singles[header.stamp.nanosec].track_id == people[0].track_id == 1
