"""`pose4d demo`: the main job, run by `make demo`.

This version of the project has the message package, the bag tools and the `replay`/`recorder`
nodes, but not yet the perception and tracking stages. So the demo does what exists, for real:
it starts the installed `recorder` executable, publishes a few `pose4d_msgs/JointArray`
messages through Fast DDS, stops the recorder with SIGINT and reads the bag back.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser('demo', help='run the main job (see README)',
                              description=__doc__.split('\n\n')[0])
    p.add_argument('--out', type=Path, default=Path('out'), help='output directory (out/)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import rclpy
    from pose4d_msgs.msg import Joint, JointArray

    from pose4d_ros.datasets import bag
    from pose4d_ros.nodes.convert import ns_to_stamp

    args.out.mkdir(parents=True, exist_ok=True)
    out = args.out / 'demo_skeleton_bag'
    shutil.rmtree(out, ignore_errors=True)
    recorder = subprocess.Popen(
        [str(Path(sys.prefix) / 'lib' / 'pose4d_ros' / 'recorder'), '--ros-args',
         '-p', f'recorder.output:={out}', '-p', 'recorder.topics:=[pose4d/skeleton]'],
        env=dict(os.environ))
    rclpy.init()
    node = rclpy.create_node('pose4d_demo')
    pub = node.create_publisher(JointArray, 'pose4d/skeleton', 10)
    try:
        deadline = time.monotonic() + 15
        while pub.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                raise OSError('the recorder did not subscribe within 15 s')
            rclpy.spin_once(node, timeout_sec=0.05)
        for k in range(30):
            msg = JointArray(track_id=1, score=1.0)
            msg.header.stamp = ns_to_stamp(k * 33_333_333)
            msg.header.frame_id = 'demo'
            msg.joints = [Joint(name='head', u=160.0, v=40.0 + k, source=Joint.DETECTED)]
            pub.publish(msg)
            rclpy.spin_once(node, timeout_sec=1 / 30)
        pub.wait_for_all_acked()
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        recorder.send_signal(signal.SIGINT)
        recorder.wait(15)
    count = sum(1 for _ in bag.read_messages(out))
    print(f'pose4d demo: published 30 JointArray messages on pose4d/skeleton; the recorder '
          f'executable wrote {count} of them to {out} (exit status {recorder.returncode}).')
    print('The perception and tracking stages are not part of this version yet.')
    return 0 if count == 30 and recorder.returncode == 0 else 1
