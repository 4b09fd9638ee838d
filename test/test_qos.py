"""QoS combinations, on the tracker node (its input and output are our JointArray topics).

Should work: our outputs (reliable, volatile) to a reliable or a best-effort subscriber; our
inputs (best effort: camera topics and the stages' JointArray topics alike) from a reliable or a
best-effort publisher (test_dds.py and the node tests send both). Cannot work, and must say so
in the node's log rather than stay silent: a transient-local subscriber of an output (we keep
no history for late joiners).
"""

from __future__ import annotations

from harness import start
from helpers import header_at, parts_msg


def test_qos_combinations_work_or_are_warned_about(ros, tmp_path):
    from pose4d_msgs.msg import JointArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from pose4d_ros.nodes import qos

    node = start('tracker', {}, log_dir=tmp_path)
    try:
        got = {name: ros.collect(JointArray, 'pose4d/parts/tracked', QoSProfile(
            depth=10, reliability=reliability)) for name, reliability in (
            ('reliable', ReliabilityPolicy.RELIABLE),
            ('best_effort', ReliabilityPolicy.BEST_EFFORT))}
        pub = ros.node.create_publisher(JointArray, 'pose4d/parts', qos.OUTPUT_QOS)
        ros.wait_for_subscribers(pub, timeout=30.0)
        ros.wait_for_publishers('pose4d/parts/tracked', count=1, timeout=30.0)
        header = header_at(1)
        ros.send_until_answered(
            lambda: pub.publish(parts_msg(1, header)),
            lambda: all(any(m.header == header for m in msgs) for msgs in got.values()),
            'the tracked parts to a reliable and a best-effort subscriber')

        # a late joiner asking for the last message (transient local): we offer volatile
        latched = ros.node.create_subscription(
            JointArray, 'pose4d/parts/tracked', lambda m: None,
            QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        ros.spin_until(lambda: "topic 'pose4d/parts/tracked', requesting incompatible QoS"
                       in node.output(), 15.0, 'the warning about the latched subscriber')
        # a best-effort publisher into the tracker's (best-effort) input
        lossy = ros.node.create_publisher(JointArray, 'pose4d/parts', QoSProfile(
            depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        ros.wait_for_subscribers(lossy, timeout=30.0)
        header = header_at(2)
        ros.send_until_answered(
            lambda: lossy.publish(parts_msg(2, header)),
            lambda: any(m.header == header for m in got['reliable']),
            'the parts from a best-effort publisher')
    finally:
        assert node.stop() == 0, node.output()
    text = node.output()
    assert 'Last incompatible policy: DURABILITY' in text
    assert 'offering incompatible QoS' not in text
    del latched
