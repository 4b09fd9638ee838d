"""Bytes that do not deserialize never leave a node deaf (`qos.INPUT_QOS`,
`nodes.common.subscribe`).

A `JointArray` published as 0 raw bytes by a reliable publisher once left the tracker and IK
nodes answering none of the valid messages that followed: their reliable readers waited for
that sample for good. Here each node of the per-stage graph that reads a `JointArray` gets, on
every input topic from a reliable publisher, each kind of undeserializable bytes, each followed
by one valid frame that must be answered, and counts every one that reaches it as a bad input
(a 0-byte sample is dropped by Fast DDS before it reaches the node).
"""

from __future__ import annotations

import numpy as np
import pytest
from fuzz import Target
from harness import start
from helpers import diagnostic_values, header_at

# 'empty' last: a 0-byte sample also costs its publisher the next messages inside Fast DDS (as
# many as its history holds, 10), which would hide the kinds sent after it
KINDS = {
    'header_only': lambda cdr, rng: cdr[:4],
    'random': lambda cdr, rng: rng.integers(0, 256, 300, dtype=np.uint8).tobytes(),
    'truncated': lambda cdr, rng: cdr[:len(cdr) // 2],
    'length_lie': lambda cdr, rng: cdr[:4] + b'\xff\xff\xff\x7f' * 4,
    'empty': lambda cdr, rng: b'',
}


@pytest.mark.parametrize('name', ['tracker', 'ik'])
def test_undeserializable_bytes_leave_the_node_serving(ros, tmp_path, name):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import serialize_message

    rng = np.random.default_rng(0)
    target = Target(name, ros)
    diagnostics = ros.collect(DiagnosticArray, '/diagnostics')
    node = start(name, log_dir=tmp_path)
    try:
        for pub in target.pubs.values():
            ros.wait_for_subscribers(pub, timeout=60.0)
        ros.wait_for_publishers(target.out_topic, timeout=60.0)
        k = 0

        def frames_to_answer(limit: int) -> int | None:
            """Valid frames sent at 30 fps until one is answered correctly: how many were
            sent before it (None: none of `limit` answered)."""
            nonlocal k
            headers = []
            for n in range(limit):
                k += 1
                headers.append(header_at(k))
                target.publish(target.valid(headers[-1]))
                if ros.wait(lambda: any(m.header in headers and target.correct(m)
                                        for m in target.answers), 1 / 30):
                    return n
            ros.spin_for(1.0)
            return next((n for n, h in enumerate(headers)
                         if any(m.header == h for m in target.answers)), None)

        # the first frames may meet a reader that has not matched our writer yet
        assert frames_to_answer(60) is not None, 'no answer to valid frames at start'
        ros.spin_for(0.5)
        sent = 0  # that reach the node: all but the 0-byte ones
        lost = {}
        for topic in sorted(target.topics):
            cdr = serialize_message(target.valid(header_at(0))[topic])
            for kind, make in KINDS.items():
                data = make(cdr, rng)
                target.pubs[topic].publish(data)
                sent += len(data) > 0
                # serving again within a second of frames (after a 0-byte sample, the next
                # valid ones of that publisher are lost inside Fast DDS, 10 at most)
                lost[topic, kind] = frames_to_answer(30)
                assert lost[topic, kind] is not None, (
                    f'{name}: no answer to 30 valid frames after {kind} bytes on '
                    f'{target.topics[topic][1]}\n{node.output()}')
        print(f'{name}: valid frames unanswered after each kind of bad bytes: {lost}')
        ros.spin_for(1.5)  # the next /diagnostics
        counts = diagnostic_values(diagnostics, name, 'bad_inputs')
        assert counts and counts[-1] == sent, (counts[-1:], sent)
        assert 'bytes that are not a' in node.output()
    finally:
        node.stop()
