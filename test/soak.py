"""Soak test (`make soak`): a bag replayed in a loop through the graph into the recorder.

    python test/soak.py [--seconds 600] [--bag BAG] [--out out/soak.json]

The one-process-per-stage graph (replay -> foreground -> detector -> tracker -> ik, and the
recorder) runs for `--seconds` with the replay looping the bag at 1x, as `pose4d demo` starts
it. Each loop sends the bag's stamps again, backwards in time: the tracker must start a new
track each time and go on. Written to the JSON:

- `published`: skeletons the ik node says it published (`frames` on its /diagnostics; every
  frame it processes gives one); `received`: skeletons this process received; `recorded`:
  skeletons in the recorder's bag; `lost` = published - recorded;
- `rss_mb` per node: resident memory sampled every 10 s, `rss_growth_pct` from the end of the
  first minute (warm-up) to the end;
- `latency_ms`: colour frame in (its camera_info seen here) to its skeleton seen here, p50 and
  p95 over the run, `p95_first_minute` and `p95_last_minute`;
- `tracks`: distinct track ids in the recorded skeletons (a new one per loop at least) and the
  largest joint coordinate seen (a filter that exploded would show it).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import conftest  # noqa: F401  (DDS on this machine, the project's profile, a domain id)
import numpy as np
from fuzz import rss_mb

from pose4d_ros.core.files import write_json
from pose4d_ros.datasets import bag, cad60_bag
from pose4d_ros.graph.run import CONNECTIONS, STAGES, Graph, default_bag

SAMPLE_S = 10.0  # RSS sampling period
WARM_UP_S = 60.0  # the RSS reference is taken after this (or a tenth of a short run)


def soak(bag_path: Path, seconds: float, work: Path) -> dict[str, object]:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from pose4d_msgs.msg import JointArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo

    from pose4d_ros.nodes import qos
    from pose4d_ros.wire import stamp_to_ns

    recorded = work / 'soak_run'
    graph = Graph(work)
    rclpy.init()
    node = rclpy.create_node('pose4d_soak')
    entered: dict[int, float] = {}
    latencies: list[tuple[float, float]] = []  # (time since start, ms)
    received = [0]
    ik_frames = [0]
    t0 = time.monotonic()

    def on_skeleton(msg) -> None:
        now = time.monotonic()
        received[0] += 1
        t_in = entered.pop(stamp_to_ns(msg.header.stamp), None)
        if t_in is not None:
            latencies.append((now - t0, (now - t_in) * 1e3))

    def on_diagnostics(msg) -> None:
        for status in msg.status:
            if status.name == 'pose4d: ik':
                ik_frames[0] = max(ik_frames[0], int(next(
                    kv.value for kv in status.values if kv.key == 'frames')))

    node.create_subscription(JointArray, 'pose4d/skeleton', on_skeleton, qos.OUTPUT_QOS)
    node.create_subscription(
        CameraInfo, 'camera/color/camera_info',
        lambda m: entered.__setitem__(stamp_to_ns(m.header.stamp), time.monotonic()),
        QoSProfile(depth=300, reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    rss: dict[str, list[tuple[float, float]]] = {}
    try:
        graph.start('recorder', {'recorder.output': str(recorded),
                                 'recorder.topics': ['pose4d/skeleton']})
        for exe in STAGES:
            graph.start(exe, {})
        deadline = time.monotonic() + 120.0
        while any(node.count_subscribers(t) < n for t, n in CONNECTIONS.items()):
            graph.check_alive()
            if time.monotonic() > deadline:
                raise OSError('the graph did not connect within 120 s')
            rclpy.spin_once(node, timeout_sec=0.1)
        played = [t.lstrip('/') for t in bag.topics(bag_path) if t.startswith('/camera/')]
        graph.start('replay', {'replay.bag': str(bag_path), 'replay.loop': True,
                               'replay.topics': played, 'replay.delay_s': 0.5,
                               'replay.wait_for_subscribers': [
                                   f'{t}={node.count_subscribers(t)}' for t in played]})
        t0 = time.monotonic()
        next_sample = t0
        while time.monotonic() - t0 < seconds:
            graph.check_alive()
            if graph.procs['replay'].poll() is not None:
                raise OSError(f'replay exited ({graph.procs["replay"].returncode}):\n'
                              f'{graph.tail("replay")}')
            if time.monotonic() >= next_sample:
                for exe, proc in graph.procs.items():
                    rss.setdefault(exe, []).append((time.monotonic() - t0, rss_mb(proc.pid)))
                next_sample += SAMPLE_S
            rclpy.spin_once(node, timeout_sec=0.05)
        graph.procs['replay'].send_signal(2)  # SIGINT: no more frames
        graph.procs['replay'].wait(15)
        quiet = time.monotonic()
        while time.monotonic() - quiet < 3.0:  # drain, and the ik node's last /diagnostics
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        codes = graph.stop()
    graph.raise_unless_clean(codes)
    skeletons = [bag.deserialize(m) for m in bag.read_messages(recorded, ['/pose4d/skeleton'])]
    coords = [abs(c) for s in skeletons for j in s.joints
              for c in (j.u, j.v, j.position.x, j.position.y, j.position.z) if np.isfinite(c)]
    lat = np.array(latencies) if latencies else np.zeros((0, 2))
    warm = min(WARM_UP_S, seconds / 10.0)

    def p95(sel) -> float | None:
        return float(np.percentile(lat[sel, 1], 95)) if sel.any() else None

    growth = {}
    for exe, samples in rss.items():
        if exe == 'replay':
            continue
        ref = next((mb for t, mb in samples if t >= warm), samples[0][1])
        growth[exe] = round(100.0 * (samples[-1][1] / ref - 1.0), 2)
    return {
        'bag': str(bag_path), 'seconds': seconds,
        'frames_per_loop': bag.topics(bag_path)[cad60_bag.COLOR_TOPIC].count,
        'published': ik_frames[0], 'received': received[0], 'recorded': len(skeletons),
        'lost': ik_frames[0] - len(skeletons),
        'rss_growth_pct': growth,
        'rss_mb': {exe: [round(mb, 1) for _, mb in samples] for exe, samples in rss.items()},
        'latency_ms': {
            'p50': float(np.percentile(lat[:, 1], 50)) if len(lat) else None,
            'p95': p95(np.ones(len(lat), bool)),
            'p95_first_minute': p95(lat[:, 0] < 60.0),
            'p95_last_minute': p95(lat[:, 0] >= seconds - 60.0), 'n': len(lat)},
        'tracks': {'distinct': len({s.track_id for s in skeletons}),
                   'largest_coordinate': max(coords, default=0.0)},
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--seconds', type=float, default=600.0)
    p.add_argument('--bag', type=Path, default=None, help='default: the bundled sample bag')
    p.add_argument('--out', type=Path, default=Path('out/soak.json'))
    args = p.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix='pose4d_soak_'))
    res = soak(args.bag or default_bag(), args.seconds, work)
    write_json(args.out, res)
    lat = res['latency_ms']
    print(f'published {res["published"]}, recorded {res["recorded"]}, lost {res["lost"]}; '
          f'RSS growth {res["rss_growth_pct"]} %; latency p50 {lat["p50"]:.1f} ms, p95 '
          f'{lat["p95"]:.1f} ms (first minute {lat["p95_first_minute"]:.1f}, last '
          f'{lat["p95_last_minute"]:.1f}); {res["tracks"]["distinct"]} tracks; wrote {args.out} '
          f'(logs in {work / "logs"})')
    return 0 if res['lost'] == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
