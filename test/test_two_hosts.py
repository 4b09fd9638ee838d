"""The camera on one computer, perception on another (`two_hosts.py`): two network namespaces
joined by a veth link, made by the test and always deleted, each with its own /dev/shm, so that
every camera frame crosses the link (its byte counters are checked). Host A replays the bag
best effort (as a camera driver publishes) and consumes /pose4d/skeleton; host B runs the
`pipeline` node; discovery by ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET, the shared Fast DDS profile
(config/fastdds.xml) on both. Needs root (ip netns, tc): skipped otherwise."""

from __future__ import annotations

import json
import subprocess

import pytest
import two_hosts
from harness import executable

pytestmark = pytest.mark.slow

BENCH_BAG = two_hosts.REPO / 'data' / 'synth' / 'bench300_bag'


@pytest.fixture(scope='module', autouse=True)
def netns():
    if (reason := two_hosts.unavailable()) is not None:
        pytest.skip(reason)


def _raw_bytes(width: int, height: int) -> int:
    return width * height * (3 + 2)  # rgb8 colour and 16UC1 depth


def _received(run: dict) -> int:
    """Frames that reached host B's pipeline node: those it processed and those its one-deep
    queue dropped for a newer frame (its CPU, not the link)."""
    return run['pipeline_frames'] + run['pipeline_dropped']


def test_every_frame_across_the_link_with_one_hosts_latency(tmp_path):
    """The 300-frame bench bag at 1x: every frame reaches host B across the link (none lost in
    transport) and every skeleton comes back, and the p95 latency (colour in -> skeleton out, on
    host A's clock) is within 10 ms of the same graph on one host. One host and two hosts run
    alternately twice, and each's best run is compared: the 2-core machine is shared, and a
    busy moment costs one run tens of ms whatever the link."""
    if not BENCH_BAG.is_dir():
        pytest.skip(f'needs {BENCH_BAG} (made by `make results RESULTS_ONLY=bench_graph300`)')
    runs: dict[int, list[dict]] = {1: [], 2: []}
    for k in range(2):
        for hosts in (1, 2):
            runs[hosts].append(two_hosts.run(BENCH_BAG, tmp_path / f'{hosts}_{k}', hosts=hosts))
    print(json.dumps(runs, indent=1))
    for r in runs[2]:
        # nothing lost on the link: every frame reached the pipeline (processed, or dropped by
        # its own queue for a newer one when the shared CPU was busy: that is not transport)
        assert _received(r) == r['frames'] == 300, r
        assert r['link']['a_to_b'] >= 300 * _raw_bytes(320, 240), r  # all of it crossed
    assert max(r['frames_out'] for r in runs[2]) == 300
    one = min(r['latency_ms']['p95'] for r in runs[1])
    two = min(r['latency_ms']['p95'] for r in runs[2])
    assert two <= one + 10.0, (one, two)


def test_vga_over_100_mbit(tmp_path, shared_data):
    """90 VGA frames (3 s at 30 fps): without a limit all of them cross; on a 100 Mbit/s link
    (tbf on both ends) the link carries no more than its rate, and raw VGA RGB-D (369 Mbit/s
    at 30 fps) does not fit: what arrives is measured (printed), and fewer frames come out.
    (Whether the pipeline keeps up with VGA on a shared 2-core machine is the bench's question,
    not the link's: a frame its queue dropped still crossed.)"""
    exe = [str(executable('pose4d'))]
    subprocess.run([*exe, 'synth', '--utkinect', str(shared_data / 'utkinect'), '--out',
                    str(tmp_path / 'set'), '--seed', '300', '--takes', 's07_e01',
                    '--videos-per-take', '1', '--frames', '90', '--stride', '1', '--width',
                    '640', '--height', '480', '--quiet'], check=True)
    subprocess.run([*exe, 'cad60-to-bag', str(tmp_path / 'set'), str(tmp_path / 'bag')],
                   check=True, capture_output=True)
    free = two_hosts.run(tmp_path / 'bag', tmp_path / 'free', hosts=2)
    limited = two_hosts.run(tmp_path / 'bag', tmp_path / 'limited', hosts=2, rate_mbit=100)
    print(json.dumps({'unlimited': free, '100mbit': limited}, indent=1))
    assert _received(free) == 90 and free['link']['a_to_b'] >= 90 * _raw_bytes(640, 480)
    # the drain (3 s) after the replay included: the limit held
    assert limited['link']['a_to_b'] <= 1.05 * 100e6 / 8 * (limited['play_s'] + 3.0)
    assert limited['frames_out'] < 90 and limited['pipeline_frames'] < 90
