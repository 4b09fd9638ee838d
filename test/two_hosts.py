"""Two hosts on one machine: the camera's computer and the perception computer as two Linux
network namespaces joined by a virtual Ethernet link (veth), made here and always deleted.

Host A (the camera's computer) runs the `replay` of a bag (the camera driver) and a consumer
of /pose4d/skeleton (`probe`, below: what a robot's behaviour would be); host B runs the graph
(the `pipeline` node). Each host has its own /dev/shm (a directory of the machine's /dev/shm
bound over it for that host's processes only), so Fast DDS cannot carry samples between them
through shared memory: everything crosses the link, as between two computers, and the link's
byte counters show it. Each namespace has only its loopback and its end of the link, with
private addresses (10.255.77.1/30, .2): no packet can reach any other address.
`rate_mbit` puts a token bucket (tc tbf) on both ends of the link: a 100 Mbit/s Ethernet.

    sudo .venv/bin/python test/two_hosts.py BAG --hosts 2 [--rate-mbit 100] --out out/two_hosts

prints and writes (--json) frames in and out, latency (camera_info in -> skeleton out, both
seen by the probe on host A's clock: the round trip across the link), and the link's bytes.
Needs root (`ip netns`, `tc`). `discovery`: 'subnet' (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET,
multicast on the link) or 'peers' (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST with
ROS_STATIC_PEERS naming the other host: unicast only).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
NS = ('pose4d_host_a', 'pose4d_host_b')
DEV = ('p4d_veth_a', 'p4d_veth_b')
ADDR = ('10.255.77.1', '10.255.77.2')
DOMAIN = 61  # our own ROS_DOMAIN_ID (60-69), though nothing outside the namespaces can hear
PLAYED = ('camera/color/image_raw', 'camera/depth/image_raw', 'camera/color/camera_info')


def unavailable() -> str | None:
    """Why two network namespaces cannot be made here, or None."""
    if os.geteuid() != 0:
        return 'needs root for ip netns and tc (network namespaces, a veth link)'
    for tool in ('ip', 'tc'):
        if shutil.which(tool) is None:
            return f'needs the {tool} command (iproute2)'
    probe = 'pose4d_netns_probe'
    made = subprocess.run(['ip', 'netns', 'add', probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f'ip netns add failed: {made.stderr.strip()}'
    subprocess.run(['ip', 'netns', 'del', probe], capture_output=True)
    return None


def _ip(*args: str) -> None:
    subprocess.run(['ip', *args], check=True, capture_output=True, text=True)


class Hosts:
    """The namespaces, their link and their processes; `close()` stops the processes and
    deletes the namespaces (and with them the link) whatever happened."""

    def __init__(self, out: Path, *, hosts: int = 2, rate_mbit: float | None = None) -> None:
        self.out, self.hosts = out, hosts
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        out.mkdir(parents=True, exist_ok=True)
        self.shm = [Path('/dev/shm') / f'{ns}_{os.getpid()}' for ns in NS[:hosts]]
        self.close()  # the namespaces of a run that was killed
        try:
            for ns, shm in zip(NS, self.shm, strict=False):
                _ip('netns', 'add', ns)
                _ip('-n', ns, 'link', 'set', 'lo', 'up')
                shm.mkdir(mode=0o1777)
            if hosts == 2:
                _ip('link', 'add', DEV[0], 'netns', NS[0], 'type', 'veth', 'peer', 'name',
                    DEV[1], 'netns', NS[1])
                for ns, dev, addr in zip(NS, DEV, ADDR, strict=True):
                    _ip('-n', ns, 'addr', 'add', f'{addr}/30', 'dev', dev)
                    _ip('-n', ns, 'link', 'set', dev, 'up')
                    # multicast (SUBNET discovery) leaves by the link; nothing else is routed
                    _ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', dev)
                    if rate_mbit:
                        subprocess.run(['ip', 'netns', 'exec', ns, 'tc', 'qdisc', 'add', 'dev',
                                        dev, 'root', 'tbf', 'rate', f'{rate_mbit}mbit',
                                        'burst', '128kb', 'latency', '50ms'],
                                       check=True, capture_output=True, text=True)
        except BaseException:
            self.close()
            raise

    def host_of(self, name: str) -> int:
        return 0 if self.hosts == 1 else {'replay': 0, 'probe': 0}.get(name, 1)

    def start(self, name: str, cmd: list[str], env: dict[str, str]) -> subprocess.Popen:
        """`cmd` as process `name` on its host: in its network namespace, with the host's
        /dev/shm (bound in a mount namespace of the process's own)."""
        h = self.host_of(name)
        shell = 'mount --bind "$0" /dev/shm && exec "$@"'
        self.logs[name] = self.out / f'{name}.log'
        self.procs[name] = subprocess.Popen(
            ['ip', 'netns', 'exec', NS[h], 'sh', '-c', shell, str(self.shm[h]), *cmd],
            stdout=self.logs[name].open('w'), stderr=subprocess.STDOUT, env=env)
        return self.procs[name]

    def link_bytes(self) -> dict[str, int]:
        """Bytes sent by each end of the link so far (its counters; 0 on one host)."""
        if self.hosts == 1:
            return {'a_to_b': 0, 'b_to_a': 0}
        out = {}
        for ns, dev, key in zip(NS, DEV, ('a_to_b', 'b_to_a'), strict=True):
            text = subprocess.run(['ip', '-n', ns, '-s', '-j', 'link', 'show', dev],
                                  check=True, capture_output=True, text=True).stdout
            out[key] = int(json.loads(text)[0]['stats64']['tx']['bytes'])
        return out

    def stop(self, name: str, timeout: float = 15.0) -> int:
        proc = self.procs[name]
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.wait(5)

    def close(self) -> None:
        for name in list(self.procs):
            self.stop(name)
        for ns in NS:
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True)
        for shm in self.shm:
            shutil.rmtree(shm, ignore_errors=True)


def _env(hosts: int, discovery: str, peer: str | None, profile: Path | None = None
         ) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(DOMAIN), AMENT_PREFIX_PATH=sys.prefix,
               FASTRTPS_DEFAULT_PROFILES_FILE=str(profile or REPO / 'config' / 'fastdds.xml'),
               RCUTILS_COLORIZED_OUTPUT='0')
    env.pop('ROS_STATIC_PEERS', None)
    if hosts == 1:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    elif discovery == 'subnet':
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
    elif discovery == 'peers':
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        env['ROS_STATIC_PEERS'] = peer or ''
    else:
        raise ValueError(f'discovery {discovery!r}: expected subnet or peers')
    return env


def _exe(name: str) -> str:
    return str(Path(sys.prefix) / 'lib' / 'pose4d_ros' / name)


def run(bag_path: Path, out: Path, *, hosts: int = 2, rate_mbit: float | None = None,
        discovery: str = 'subnet', rate: float = 1.0, best_effort: bool = True,
        profile_a: Path | None = None, timeout: float = 90.0) -> dict[str, Any]:
    """Replay `bag_path` on host A through the pipeline node on host B (or both on one host),
    measured by the probe on host A; the figures as a dict (see `summary`). `profile_a`: the
    Fast DDS profile of host A's processes (default config/fastdds.xml, as host B's)."""
    from pose4d_ros.datasets import bag, cad60_bag
    from pose4d_ros.nodes.params import override_args

    frames = bag.topics(bag_path)[cad60_bag.COLOR_TOPIC].count
    result = out / 'probe.json'
    ready = out / 'probe.ready'
    for path in (result, ready):
        path.unlink(missing_ok=True)
    net = Hosts(out, hosts=hosts, rate_mbit=rate_mbit)
    try:
        env_a = _env(hosts, discovery, ADDR[1], profile_a)
        env_b = _env(hosts, discovery, ADDR[0])
        net.start('pipeline', [_exe('pipeline'), '--ros-args'], env_b)
        net.start('probe', [sys.executable, __file__, 'probe', '--out', str(result),
                            '--ready', str(ready)], env_a)
        deadline = time.monotonic() + timeout
        while not ready.exists():  # the probe has matched the pipeline across the link
            for name in ('pipeline', 'probe'):
                if net.procs[name].poll() is not None:
                    raise OSError(f'{name} exited: {net.logs[name].read_text()[-2000:]}')
            if time.monotonic() > deadline:
                raise OSError(f'no connection within {timeout} s (see {out})')
            time.sleep(0.1)
        before = net.link_bytes()
        played = [f'{t}={n}' for t, n in zip(PLAYED, (1, 1, 2), strict=True)]
        replay = net.start('replay', [_exe('replay'), '--ros-args', *override_args({
            'replay.bag': str(bag_path), 'replay.rate': rate, 'replay.best_effort': best_effort,
            'replay.topics': list(PLAYED), 'replay.delay_s': 0.5,
            'replay.wait_for_subscribers': played, 'replay.wait_timeout_s': timeout})], env_a)
        t_play = time.monotonic()
        if replay.wait(timeout + 60) != 0:
            raise OSError(f'replay failed: {net.logs["replay"].read_text()[-2000:]}')
        play_s = time.monotonic() - t_play
        time.sleep(3.0)  # the last frames drain
        after = net.link_bytes()
        if net.stop('probe') != 0 or not result.exists():
            raise OSError(f'probe failed: {net.logs["probe"].read_text()[-2000:]}')
        pipeline_code = net.stop('pipeline')
    finally:
        net.close()
    probe = json.loads(result.read_text())
    return summary(probe, frames, hosts=hosts, rate_mbit=rate_mbit, discovery=discovery,
                   best_effort=best_effort, profile_a=str(profile_a or ''),
                   link={k: after[k] - before[k] for k in after}, play_s=play_s,
                   pipeline_exit=pipeline_code)


def summary(probe: dict[str, dict[str, float]], frames: int, **facts: Any) -> dict[str, Any]:
    """Frames in and out, and latency (p50, p95, max: ms) of the frames seen both ways."""
    import numpy as np

    entered, left = probe['entered'], probe['left']
    lat = np.array([(left[s] - entered[s]) * 1e3 for s in left if s in entered])
    q = (lambda p: round(float(np.percentile(lat, p)), 1)) if len(lat) else (lambda p: None)
    stage = probe.get('stages', {}).get('pipeline', {})
    return {**facts, 'frames': frames, 'frames_in': len(entered), 'frames_out': len(left),
            # the pipeline's own count (its last /diagnostics): frames it took in, and those it
            # dropped, working on newer ones, when the CPU could not keep up
            'pipeline_frames': int(stage.get('frames', -1)),
            'pipeline_dropped': int(stage.get('dropped', -1)),
            'latency_ms': {'p50': q(50), 'p95': q(95),
                           'max': round(float(lat.max()), 1) if len(lat) else None}}


def probe_main(out: Path, ready: Path) -> int:
    """Host A's consumer: {stamp: monotonic s} when each frame's camera_info and its
    /pose4d/skeleton reached it, and the stages' last /diagnostics; `ready` written once the
    pipeline's skeleton publisher is matched; the JSON written on SIGINT."""
    import rclpy

    from pose4d_ros.graph.run import probe

    rclpy.init()
    node = rclpy.create_node('skeleton_consumer')
    entered, left, stages = probe(node)
    stopping = []
    signal.signal(signal.SIGINT, lambda *_: stopping.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    try:
        while not stopping:
            rclpy.spin_once(node, timeout_sec=0.05)
            if not ready.exists() and node.count_publishers('/pose4d/skeleton') > 0:
                ready.write_text('matched\n')
    finally:
        out.write_text(json.dumps({'entered': {str(k): v for k, v in entered.items()},
                                   'left': {str(k): v for k, v in left.items()},
                                   'stages': stages}))
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    sub = parser.add_subparsers(dest='verb')
    p = sub.add_parser('probe')
    p.add_argument('--out', type=Path, required=True)
    p.add_argument('--ready', type=Path, required=True)
    r = sub.add_parser('run')
    r.add_argument('bag', type=Path)
    r.add_argument('--hosts', type=int, choices=(1, 2), default=2)
    r.add_argument('--rate-mbit', type=float)
    r.add_argument('--discovery', choices=('subnet', 'peers'), default='subnet')
    r.add_argument('--rate', type=float, default=1.0)
    r.add_argument('--profile-a', type=Path, help="host A's Fast DDS profile")
    r.add_argument('--reliable', action='store_true',
                   help="the camera topics with the bag's recorded QoS (reliable), not best "
                   'effort as camera drivers publish')
    r.add_argument('--out', type=Path, default=REPO / 'out' / 'two_hosts')
    r.add_argument('--json', type=Path)
    args = parser.parse_args(argv)
    if args.verb == 'probe':
        return probe_main(args.out, args.ready)
    if args.verb != 'run':
        parser.error('a verb: run or probe')
    if (reason := unavailable()) is not None:
        print(f'cannot run: {reason}', file=sys.stderr)
        return 2
    figures = run(args.bag, args.out, hosts=args.hosts, rate_mbit=args.rate_mbit,
                  discovery=args.discovery, rate=args.rate, best_effort=not args.reliable,
                  profile_a=args.profile_a)
    print(json.dumps(figures, indent=1))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
