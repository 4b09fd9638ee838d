"""Fuzzing harness for the nodes (`make fuzz`; a short run is in `make test`, test_fuzz.py).

Each input-consuming node (foreground, detector, tracker, ik, pipeline) is started as `ros2 run`
starts it and sent malformed messages of every kind a broken driver or a hostile publisher can
produce, in batches; after every batch it must answer a valid frame with a correct output.

    python test/fuzz.py [--n 10000] [--nodes foreground,detector,...] [--out out/fuzz.json]

Per node the JSON gives `sent` (malformed messages published), `crashes` (the process died; it
is started again), `hangs` (no answer to valid frames for `HANG_S` after a liveness failure; it
is started again), `liveness_failures` (a valid frame after a batch not answered correctly
within `ANSWER_S`), the node's resident memory: `rss_mb_valid_warm_up` (after 5 valid frames),
`rss_mb_start` (after `WARM_UP_PASSES` frames of each malformed kind: the paths they take
have run and reached their buffers' size),
`rss_mb_mid` (half-way) and `rss_mb_end`, which kinds were sent how often, and the node's
own counts on /diagnostics (frames, dropped, bad_inputs).
"""

from __future__ import annotations

import argparse
import array
import math
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import conftest  # noqa: F401  (DDS on this machine, the project's profile, a domain id)
import numpy as np
from harness import RosPeer, start
from helpers import INTR, header_at, parts_msg

from pose4d_ros.core.camera import depth_to_millimetres
from pose4d_ros.core.files import write_json
from pose4d_ros.datasets.sources import load_frames

NODES = ('foreground', 'detector', 'tracker', 'ik', 'pipeline')
# `make fuzz` fails when a node's resident memory grows more than this share from after the
# warm-up (every kind of frame sent three times) to the end: memory flat (`make fuzz` with
# 10,000 a node measured +0.1 % to +1.1 %, docs/NOTES.md)
MAX_RSS_GROWTH = 0.05
BATCH = 50  # malformed messages between two valid frames
ANSWER_S = 10.0  # a valid frame must be answered within this (3 sends)
HANG_S = 30.0  # after a liveness failure: no answer for this long is a hang
WARM_UP_PASSES = 3  # frames of each malformed kind before the reference RSS
PAUSE_S = 0.004  # between two malformed frames (a node refuses one in well under this)
ENCODINGS = ('rgb8', 'bgr8', 'mono8', '8UC3', '16UC1', '32FC1', 'yuv422', 'bgra8', 'mono16',
             'bayer_rggb8', '', 'x' * 300)


def _image(Image, header, width, height, encoding, step, data: bytes, bigendian=0):
    msg = Image(header=header, width=width, height=height, encoding=encoding, step=step,
                is_bigendian=bigendian)
    msg.data = array.array('B', data)
    return msg


def image_cases(Image, valid: dict[str, object], rng: np.random.Generator
                ) -> dict[str, Callable[[object], object]]:
    """Malformed variants of the valid images {'color': msg, 'depth': msg, ...}, each made for
    a given header."""
    images = [valid[k] for k in ('color', 'depth', 'mask') if k in valid]
    color, depth = valid.get('color', images[0]), valid.get('depth', images[0])
    w, h = images[0].width, images[0].height

    def like(msg, header, **kw):
        fields = dict(width=msg.width, height=msg.height, encoding=msg.encoding, step=msg.step,
                      data=bytes(msg.data))
        fields.update(kw)
        return _image(Image, header, **fields)

    def depth_values(header, values):
        return _image(Image, header, w, h, '32FC1', 4 * w,
                      np.full((h, w), values, np.float32).tobytes())

    return {
        'encoding': lambda hd: like(images[rng.integers(len(images))], hd,
                                    encoding=str(rng.choice(ENCODINGS))),
        'width': lambda hd: like(color, hd, width=int(rng.integers(0, 4 * w))),
        'height': lambda hd: like(depth, hd, height=int(rng.integers(0, 4 * h))),
        'step': lambda hd: like(color, hd, step=int(rng.integers(0, 8 * w))),
        'data_short': lambda hd: like(depth, hd, data=bytes(depth.data)[
            :int(rng.integers(0, len(depth.data)))]),
        'data_long': lambda hd: like(color, hd, data=bytes(color.data) + b'\0' * 1000),
        'empty': lambda hd: _image(Image, hd, 0, 0, 'rgb8', 0, b''),
        'absurd_size': lambda hd: like(color, hd, width=2**31 - 1, height=2**31 - 1,
                                       step=2**32 - 1),
        'bigendian': lambda hd: like(depth, hd, bigendian=1),
        'depth_nan': lambda hd: depth_values(hd, np.nan),
        'depth_inf': lambda hd: depth_values(hd, np.inf),
        'depth_negative': lambda hd: depth_values(hd, -1.0),
        'depth_zero': lambda hd: depth_values(hd, 0.0),
        'depth_huge': lambda hd: depth_values(hd, 1e30),
        'depth_65535mm': lambda hd: _image(Image, hd, w, h, '16UC1', 2 * w,
                                           np.full((h, w), 65535, np.uint16).tobytes()),
        'small_image': lambda hd: _image(Image, hd, w // 2, h // 2, 'rgb8', 3 * (w // 2),
                                         bytes(3 * (w // 2) * (h // 2))),
        'noise_bytes': lambda hd: like(color, hd, data=rng.integers(
            0, 256, len(color.data), dtype=np.uint8).tobytes()),
    }


def info_cases(CameraInfo, valid, rng: np.random.Generator) -> dict[str, Callable]:
    """Malformed camera_info variants."""
    def with_k(hd, k, **kw):
        msg = CameraInfo(header=hd, width=valid.width, height=valid.height,
                         distortion_model=valid.distortion_model, d=list(valid.d),
                         r=list(valid.r), p=list(valid.p))
        msg.k = [float(x) for x in k]
        for key, value in kw.items():
            setattr(msg, key, value)
        return msg

    k = np.array(valid.k, np.float64)
    return {
        'k_zero': lambda hd: with_k(hd, np.zeros(9)),
        'k_nan': lambda hd: with_k(hd, np.where(rng.random(9) < 0.5, np.nan, k)),
        'k_inf': lambda hd: with_k(hd, np.where(rng.random(9) < 0.5, np.inf, k)),
        'k_huge': lambda hd: with_k(hd, k * 1e300),
        'k_tiny': lambda hd: with_k(hd, k * 1e-5),
        'k_negative': lambda hd: with_k(hd, -k),
        'size_zero': lambda hd: with_k(hd, k, width=0, height=0),
        'size_wrong': lambda hd: with_k(hd, k, width=int(rng.integers(1, 5000)),
                                        height=int(rng.integers(1, 5000))),
        'distortion_long': lambda hd: with_k(hd, k, d=[float(x) for x in rng.normal(size=1000)],
                                             distortion_model='x' * 1000),
    }


def joint_cases(JointArray, Joint, valid, rng: np.random.Generator) -> dict[str, Callable]:
    """Malformed JointArray variants."""
    def edit(hd, fn):
        msg = JointArray(header=hd, track_id=valid.track_id, score=valid.score)
        msg.joints = [Joint(name=j.name, u=j.u, v=j.v, position=j.position,
                            confidence=j.confidence, source=j.source,
                            position_covariance=j.position_covariance) for j in valid.joints]
        fn(msg)
        return msg

    def some(msg):
        return [msg.joints[i] for i in rng.choice(len(msg.joints), 3, replace=False)]

    def set_all(attr, value):
        def fn(msg):
            for j in some(msg):
                setattr(j, attr, value)
        return fn

    def positions(value):
        def fn(msg):
            for j in some(msg):
                j.position.x = j.position.y = j.position.z = value
        return fn

    def covariance(msg):
        for j in some(msg):
            j.position_covariance = [float('nan')] * 9

    return {
        'uv_nan': lambda hd: edit(hd, set_all('u', math.nan)),
        'uv_inf': lambda hd: edit(hd, set_all('v', math.inf)),
        'uv_huge': lambda hd: edit(hd, set_all('u', 1e308)),
        'position_nan': lambda hd: edit(hd, positions(math.nan)),
        'position_inf': lambda hd: edit(hd, positions(math.inf)),
        'position_huge': lambda hd: edit(hd, positions(1e308)),
        'confidence_bad': lambda hd: edit(hd, set_all('confidence', float(
            rng.choice([1e30, -1.0, math.nan, math.inf])))),
        'source_bad': lambda hd: edit(hd, set_all('source', int(rng.integers(4, 256)))),
        'name_unknown': lambda hd: edit(hd, set_all('name', 'x' * int(rng.integers(0, 500)))),
        'name_repeated': lambda hd: edit(hd, set_all('name', valid.joints[0].name)),
        'no_joints': lambda hd: edit(hd, lambda m: setattr(m, 'joints', [])),
        'thousand_joints': lambda hd: edit(hd, lambda m: setattr(m, 'joints', m.joints * 100)),
        'covariance_nan': lambda hd: edit(hd, covariance),
        'teleport': lambda hd: edit(hd, lambda m: [setattr(j, 'u', j.u + 1e6)
                                                   for j in m.joints]),
    }


def raw_cases(topics: list[str], rng: np.random.Generator) -> dict[str, Callable]:
    """Serialized bytes that are not (or not quite) a message of the topic's type, published as
    they are (`Publisher.publish(bytes)`), as a broken driver, bridge or replay can send them:
    each maker takes the valid messages of a frame and returns {topic key: bytes}."""
    from rclpy.serialization import serialize_message

    def on_one(make):
        def fn(valid: dict[str, object]) -> dict[str, bytes]:
            key = str(rng.choice(topics))
            return {key: make(serialize_message(valid[key]))}
        return fn

    def noise(n: int) -> bytes:
        return rng.integers(0, 256, n, dtype=np.uint8).tobytes()

    def flipped(cdr: bytes) -> bytes:
        data = bytearray(cdr)
        for i in rng.integers(4, len(data), 8):
            data[i] ^= int(rng.integers(1, 256))
        return bytes(data)

    return {
        'raw_empty': on_one(lambda cdr: b''),
        'raw_header_only': on_one(lambda cdr: cdr[:4]),
        'raw_random': on_one(lambda cdr: noise(int(rng.integers(1, 2000)))),
        'raw_truncated': on_one(lambda cdr: cdr[:int(rng.integers(4, len(cdr)))]),
        'raw_oversized': on_one(lambda cdr: cdr + noise(int(rng.integers(1, 65536)))),
        'raw_flipped': on_one(flipped),
    }


def stamp_cases(valid_k: int) -> dict[str, Callable[[], object]]:
    """Headers that lie: backwards, repeated, far future, odd frame ids."""
    from pose4d_ros.nodes.convert import ns_to_stamp

    def far_future():
        hd = header_at(valid_k)
        hd.stamp = ns_to_stamp(2**62)
        return hd

    def frame_id(text):
        def fn():
            hd = header_at(valid_k + 1)
            hd.frame_id = text
            return hd
        return fn

    return {'stamp_backwards': lambda: header_at(valid_k - 1000),
            'stamp_repeated': lambda: header_at(valid_k),
            'stamp_far_future': far_future,
            'frame_id_empty': frame_id(''),
            'frame_id_long': frame_id('f' * 10000)}


# the valid frame: the first of the project's own sample bag (a rendered person, held-out
# motion). The start-up warm-up's slab figure (`core.warm_up.warm_up_frame`) is no person to a
# part model that learned from people: the photograph network fine-tuned on renders in their
# rooms scores it 4.3, under the tracker's birth score, where the network before gave 6.1
SAMPLE_BAG = Path(__file__).resolve().parents[1] / 'bags' / 'sample'


def valid_frame() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Colour, depth (metres) and the person's mask of the sample bag's first frame."""
    frame = load_frames([str(SAMPLE_BAG)])[0]
    assert frame.intrinsics == INTR, (frame.intrinsics, INTR)
    return frame.color, frame.depth_m, frame.mask


class Target:
    """One node under fuzz: its inputs, a valid frame, its answer and what makes it correct."""

    def __init__(self, name: str, ros: RosPeer) -> None:
        from pose4d_msgs.msg import Joint, JointArray
        from sensor_msgs.msg import CameraInfo, Image

        from pose4d_ros.nodes import qos
        from pose4d_ros.nodes.convert import array_to_image, intrinsics_to_msg

        self.name = name
        color, depth_m, mask = valid_frame()
        camera = name in ('foreground', 'pipeline')
        self.topics: dict[str, tuple[type, str, object]] = {}
        if name in ('foreground', 'pipeline', 'detector'):
            # the detector reads the camera's colour too (and masks it itself), the foreground
            # while its masked colour is subscribed (below)
            self.topics['color'] = (Image, 'camera/color/image_raw', qos.SENSOR_QOS)
            self.topics['depth'] = (Image, 'camera/depth/image_raw' if camera
                                    else 'pose4d/foreground/depth', qos.SENSOR_QOS)
            self.topics['info'] = (CameraInfo, 'camera/color/camera_info', qos.SENSOR_QOS)
        if name == 'detector':
            self.topics['mask'] = (Image, 'pose4d/foreground/mask', qos.SENSOR_QOS)
        if name == 'tracker':
            self.topics['parts'] = (JointArray, 'pose4d/parts', qos.OUTPUT_QOS)
        if name == 'ik':
            self.topics['parts'] = (JointArray, 'pose4d/parts/tracked', qos.OUTPUT_QOS)
            self.topics['depth'] = (Image, 'pose4d/foreground/depth', qos.SENSOR_QOS)
            self.topics['info'] = (CameraInfo, 'camera/color/camera_info', qos.SENSOR_QOS)
        out = {'foreground': (Image, 'pose4d/foreground/mask'),
               'detector': (JointArray, 'pose4d/parts'),
               'tracker': (JointArray, 'pose4d/parts/tracked'),
               'ik': (JointArray, 'pose4d/skeleton'),
               'pipeline': (JointArray, 'pose4d/skeleton')}[name]
        self.out_type, self.out_topic = out
        self.ros = ros
        self.pubs = {k: ros.node.create_publisher(t, topic, q)
                     for k, (t, topic, q) in self.topics.items()}
        self.answers = ros.collect(self.out_type, self.out_topic, qos.OUTPUT_QOS)
        if name == 'foreground':  # the masked colour wanted: the node reads the colour too
            self.colours = ros.collect(Image, 'pose4d/foreground/color', qos.OUTPUT_QOS)

        def valid(header) -> dict[str, object]:
            msgs = {}
            if 'color' in self.topics:
                msgs['color'] = array_to_image(color, 'rgb8', header)
            if 'depth' in self.topics:
                msgs['depth'] = array_to_image(depth_to_millimetres(depth_m), '16UC1', header)
            if 'mask' in self.topics:
                msgs['mask'] = array_to_image(mask.astype(np.uint8) * 255, 'mono8', header)
            if 'info' in self.topics:
                msgs['info'] = intrinsics_to_msg(INTR, header)
            if 'parts' in self.topics:
                msgs['parts'] = parts_msg(0, header)
            return msgs

        self.valid = valid
        rng = np.random.default_rng(0)
        proto = valid(header_at(0))
        self.cases: dict[str, Callable[[object], dict[str, object]]] = {}
        images = [k for k in ('color', 'depth', 'mask') if k in self.topics]
        if images:
            for case, make in image_cases(Image, proto, rng).items():
                self.cases[case] = lambda hd, make=make: {
                    str(rng.choice(images)): make(hd)}
        if 'info' in self.topics:
            for case, make in info_cases(CameraInfo, proto['info'], rng).items():
                self.cases[case] = lambda hd, make=make: {'info': make(hd)}
        if 'parts' in self.topics:
            for case, make in joint_cases(JointArray, Joint, proto['parts'], rng).items():
                self.cases[case] = lambda hd, make=make: {'parts': make(hd)}
        for case, make in raw_cases(sorted(self.topics), rng).items():
            self.cases[case] = lambda hd, make=make: make(self.valid(hd))

    def publish(self, msgs: dict[str, object]) -> None:
        for key, msg in msgs.items():
            self.pubs[key].publish(msg)

    def correct(self, msg: object) -> bool:
        """A correct answer to the valid frame: the mask finds the person; joints are finite
        and on the image where located (the head at least)."""
        if self.out_topic == 'pose4d/foreground/mask':
            data = np.frombuffer(bytes(msg.data), np.uint8)
            return (msg.width, msg.height) == (INTR.width, INTR.height) and (data > 0).sum() > 500
        located = [j for j in msg.joints if j.source != 3]
        return any(j.name == 'head' for j in located) and all(_sane(j) for j in located)


def _sane(joint: object) -> bool:
    """On the image (grown by a tenth of its size each side: the IK completes a limb of a person
    cut by the image's border beyond it, e.g. an ankle a pixel below the bottom row), a
    confidence in [0, 1], and no 3-D position or a finite one within 20 m."""
    xyz = np.array([joint.position.x, joint.position.y, joint.position.z])
    mu, mv = 0.1 * INTR.width, 0.1 * INTR.height
    return (-mu <= joint.u < INTR.width + mu and -mv <= joint.v < INTR.height + mv
            and 0 <= joint.confidence <= 1
            and (np.isnan(xyz).all() or bool(np.isfinite(xyz).all() and abs(xyz[2]) < 20)))


def _counts(diagnostics: list) -> dict[str, dict[str, int]]:
    """Each stage's last frames, dropped and bad_inputs counts on /diagnostics."""
    last: dict[str, dict[str, int]] = {}
    for array_msg in diagnostics:
        for status in array_msg.status:
            last[status.name] = {kv.key: int(kv.value) for kv in status.values
                                 if kv.key in ('frames', 'dropped', 'bad_inputs')}
    return last


def rss_mb(pid: int) -> float:
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1]) / 1024.0
    return float('nan')


def fuzz_node(name: str, n: int, log_dir: Path, *, seed: int = 0,
              say: Callable[[str], None] = print) -> dict[str, object]:
    """Send `n` malformed messages to one node; see the module docstring for the result."""
    rng = np.random.default_rng(seed)
    ros = RosPeer(f'pose4d_fuzz_{name}')
    node = None
    result: dict[str, object] = {'sent': 0, 'crashes': 0, 'hangs': 0, 'liveness_failures': 0}
    kinds: Counter[str] = Counter()
    try:
        from diagnostic_msgs.msg import DiagnosticArray

        target = Target(name, ros)
        diagnostics = ros.collect(DiagnosticArray, '/diagnostics')
        k = 0

        def launch():
            started = start(name, {}, log_dir=log_dir)
            try:
                for pub in target.pubs.values():
                    ros.wait_for_subscribers(pub, timeout=60.0)
                ros.wait_for_publishers(target.out_topic, timeout=60.0)
            except AssertionError:
                started.kill()  # never left running: the caller has no handle on it yet
                raise
            return started

        def answered(header) -> bool:
            return any(m.header == header for m in target.answers)

        def check() -> bool:
            """One fresh valid frame, sent up to 3 times: answered correctly?"""
            nonlocal k
            k += 1
            header = header_at(k)
            msgs = target.valid(header)
            for _ in range(3):
                target.publish(msgs)
                if ros.wait(lambda: answered(header), ANSWER_S / 3):
                    break
            return any(m.header == header and target.correct(m) for m in target.answers)

        node = launch()
        for _ in range(5):  # warm-up on valid frames
            check()
        result['rss_mb_valid_warm_up'] = rss_mb(node.proc.pid)
        cases = sorted(target.cases)
        # every kind of malformed frame once (not counted as sent), so that code paths run for
        # the first time (and their buffers) are not taken for growth; then the reference RSS
        for case in cases * WARM_UP_PASSES:
            k += 1
            header = header_at(k)
            target.publish({**target.valid(header), **target.cases[case](header)})
            ros.spin_for(0.02)
        if not check():
            result['liveness_failures'] += 1
        result['rss_mb_start'] = rss_mb(node.proc.pid)
        ros.spin_for(1.5)  # the node's /diagnostics after the warm-up: the counts to subtract
        before = _counts(diagnostics)
        while result['sent'] < n:
            for _ in range(min(BATCH, n - result['sent'])):
                # a whole frame of the node's inputs, one of them (or the header) malformed, at
                # a stamp of its own, so that it pairs and reaches the node's checks
                k += 1
                case = str(rng.choice(cases + ['stamps']))
                if case == 'stamps':
                    stamps = stamp_cases(k)
                    case = str(rng.choice(sorted(stamps)))
                    target.publish(target.valid(stamps[case]()))
                else:
                    header = header_at(k)
                    target.publish({**target.valid(header), **target.cases[case](header)})
                kinds[case] += 1
                result['sent'] += 1
                ros.spin_for(PAUSE_S)
            target.answers.clear()
            if node.proc.poll() is not None:
                result['crashes'] += 1
                say(f'{name}: crashed (exit {node.proc.returncode}) after {result["sent"]} '
                    f'messages; log {node.log_path}')
                node = launch()
                continue
            if not check():
                result['liveness_failures'] += 1
                say(f'{name}: no correct answer to a valid frame after {result["sent"]} '
                    f'messages (kinds so far {dict(kinds)})')
                deadline = time.monotonic() + HANG_S
                while time.monotonic() < deadline and not check():
                    pass
                if time.monotonic() >= deadline:
                    result['hangs'] += 1
                    say(f'{name}: hangs; log {node.log_path}')
                    node.kill()
                    node = launch()
            if 'rss_mb_mid' not in result and result['sent'] >= n // 2:
                result['rss_mb_mid'] = rss_mb(node.proc.pid)
        result['rss_mb_end'] = rss_mb(node.proc.pid)
        result.setdefault('rss_mb_mid', result['rss_mb_end'])
        ros.spin_for(1.5)  # the node's last /diagnostics
        result['diagnostics'] = _counts(diagnostics)
        # what the node counted during the fuzz alone (not the warm-up's malformed frames); a
        # restarted node counts from 0, so this is exact only without crashes and hangs
        result['fuzz_counts'] = {
            stage: {k: v - before.get(stage, {}).get(k, 0) for k, v in counts.items()}
            for stage, counts in result['diagnostics'].items()}
        result['kinds'] = dict(sorted(kinds.items()))
        code = node.stop()
        node = None
        if code != 0:
            result['crashes'] += 1
            say(f'{name}: exit {code} on SIGINT')
    finally:
        if node is not None:
            node.kill()
        ros.close()
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--n', type=int, default=10000, help='malformed messages per node')
    p.add_argument('--nodes', default=','.join(NODES))
    p.add_argument('--out', type=Path, default=Path('out/fuzz.json'))
    p.add_argument('--seed', type=int, default=0)
    args = p.parse_args(argv)
    nodes = [s for s in args.nodes.split(',') if s]
    unknown = sorted(set(nodes) - set(NODES))
    if unknown:
        p.error(f'unknown node(s) {unknown}: choose from {", ".join(NODES)}')
    report: dict[str, object] = {'n_per_node': args.n, 'batch': BATCH, 'nodes': {}}
    log_dir = Path(tempfile.mkdtemp(prefix='pose4d_fuzz_'))
    for name in nodes:
        t0 = time.monotonic()
        res = fuzz_node(name, args.n, log_dir, seed=args.seed)
        res['seconds'] = round(time.monotonic() - t0, 1)
        report['nodes'][name] = res
        growth = 100.0 * (res['rss_mb_end'] / res['rss_mb_start'] - 1.0)
        print(f'{name}: sent {res["sent"]}, crashes {res["crashes"]}, hangs {res["hangs"]}, '
              f'liveness failures {res["liveness_failures"]}, RSS {res["rss_mb_start"]:.1f} -> '
              f'{res["rss_mb_end"]:.1f} MB ({growth:+.1f} %), {res["seconds"]} s', flush=True)
        write_json(args.out, report)
    print(f'wrote {args.out} (node logs in {log_dir})')
    bad = sum(r['crashes'] + r['hangs'] + r['liveness_failures']
              for r in report['nodes'].values())
    grown = {name: r['rss_mb_end'] / r['rss_mb_start'] - 1.0
             for name, r in report['nodes'].items()
             if r['rss_mb_end'] > (1.0 + MAX_RSS_GROWTH) * r['rss_mb_start']}
    if grown:
        print('memory not flat (more than '
              f'{100 * MAX_RSS_GROWTH:.0f} % growth): '
              + ', '.join(f'{name} {100 * g:+.1f} %' for name, g in grown.items()))
    return 1 if bad or grown else 0


if __name__ == '__main__':
    sys.exit(main())
