"""What every pose4d node shares: its `main()`, throttled error counting, and diagnostics
(and, in `nodes.lifecycle`, the managed node that each stage node is).

Each stage publishes a `diagnostic_msgs/DiagnosticArray` on `/diagnostics` once a second (the
diagnostics aggregator listens on that absolute name): frames in and out, rate, processing
time p50/p95, latency from the input stamp p50/p95, the time step between input stamps,
frames dropped and bad inputs.

Time: rates and latencies are measured on the node's clock, which with `use_sim_time:=true`
is the `/clock` a bag replay publishes (`replay.publish_clock:=true`), so a replayed bag is
measured in its own time. A stamp more than `CLOCK_MISMATCH_S` away from the node's clock comes
from another clock (a bag replayed without sim time, a camera whose clock is not synchronised):
the stage says so once in its log and with a `clock_mismatch` key on /diagnostics, and keeps
such frames out of its latency figures.
"""

from __future__ import annotations

import cProfile
import gc
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from pose4d_msgs.msg import JointArray, SkeletonArray
from rclpy.clock import Clock, ClockType
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from pose4d_ros import wire
from pose4d_ros.core.malloc import keep_freed_memory
from pose4d_ros.core.registration import shift_image
from pose4d_ros.core.sync import TIME_JUMP_S, StampJumps, StampSync
from pose4d_ros.core.threads import set_blas_threads
from pose4d_ros.nodes import qos
from pose4d_ros.nodes.params import ParameterError
from pose4d_ros.wire import stamp_to_ns

DIAGNOSTICS_TOPIC = '/diagnostics'
# A stamp farther than this from the node's clock was taken on another clock, seconds
CLOCK_MISMATCH_S = 10.0


class InputFailure(Exception):
    """The node cannot go on reading its input (a damaged bag, say): `run` logs it as FATAL
    and exits with status 1."""


# POSE4D_EXECUTOR=single: rclpy's SingleThreadedExecutor instead of its events executor
EXECUTOR_ENV = 'POSE4D_EXECUTOR'
# POSE4D_PROFILE=DIR: each thread of the node runs under cProfile, written at exit to
# DIR/<node>.<thread>.prof (`pose4d bench --graph --profile` reads them: calls per frame)
PROFILE_ENV = 'POSE4D_PROFILE'


class _Profiled:
    """The cProfile of one thread of a node while POSE4D_PROFILE is set (else nothing)."""

    def __init__(self, node_name: str, thread: str) -> None:
        folder = os.environ.get(PROFILE_ENV)
        self._path = (Path(folder) / f'{node_name}.{thread.replace(" ", "_")}.prof'
                      if folder else None)
        self._profile = cProfile.Profile() if folder else None

    def __enter__(self) -> _Profiled:
        if self._profile is not None:
            self._profile.enable()
        return self

    def __exit__(self, *_: object) -> None:
        if self._profile is None:
            return
        self._profile.disable()
        self._path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self._path.with_suffix('.tmp')
        self._profile.dump_stats(tmp)
        tmp.replace(self._path)


def executor(*nodes: Node) -> Executor:
    """The executor nodes spin on: rclpy's events executor (its C++ event queue: per message
    a fraction of the CPU that `SingleThreadedExecutor`'s Python wait set costs, measured in the
    README), or with POSE4D_EXECUTOR=single the `SingleThreadedExecutor`."""
    choice = os.environ.get(EXECUTOR_ENV, 'events')
    if choice not in ('events', 'single'):
        raise ParameterError(f'{EXECUTOR_ENV}={choice!r}: use events or single')
    context = nodes[0].context
    ex = (EventsExecutor(context=context) if choice == 'events'
          else SingleThreadedExecutor(context=context))
    for node in nodes:
        ex.add_node(node)
    return ex


def spin(*nodes: Node) -> None:
    """Serve the nodes' callbacks, on one executor, until the context shuts down (Ctrl-C,
    SIGTERM) or every one of them is a managed node whose lifecycle was shut down."""
    ex = executor(*nodes)
    try:
        # the events executor's spin() does not return on shutdown (rclpy 7.1.6): poll; a
        # managed node whose lifecycle was shut down (finalized) has nothing left to serve
        while (rclpy.ok(context=nodes[0].context)
               and not all(getattr(node, 'finalized', False) for node in nodes)):
            ex.spin_once(timeout_sec=0.2)
    finally:
        # the nodes out first: the events executor aborts the process when it is destroyed
        # while the nodes' entities still hold its callbacks ("Destroying callback manager
        # with callbacks remaining", rclpy 7.1.6; seen once at a node's stop in CI)
        for node in nodes:
            ex.remove_node(node)
        ex.shutdown()


def run(factory: Callable[[], Node] | Sequence[Callable[[], Node]],
        args: list[str] | None = None, body: Callable[..., None] = spin, *,
        signal_handlers: bool = True) -> int:
    """Jazzy's main(): init, spin (or `body`), clean shutdown on Ctrl-C/SIGTERM.

    `factory`: the node's class, or several (nodes composed in one process, served by one
    executor: `body(*nodes)`).
    `signal_handlers=False`: rclpy does not shut the context down on SIGINT/SIGTERM; `body`
    handles them (the recorder, which must still take what is on its way).
    Returns the exit status: 0, 2 when a parameter was refused, 1 when the node's input
    could not be read (`InputFailure`; both logged as FATAL, no traceback).
    """
    # One owner of parallelism: the graph's processes share the cores, and OpenBLAS threads
    # spin-waiting for a core make the detector's GEMM several times slower (core.threads).
    set_blas_threads(1)
    keep_freed_memory()  # a frame's blocks reused, not mapped afresh (core.malloc)
    wire.warm_up()  # the depth decoders' kernels, for message buffers (else the first frame's)
    rclpy.init(args=args, signal_handler_options=None if signal_handlers
               else SignalHandlerOptions.NO)
    nodes: list[Node] = []
    code = 0
    try:
        for make in ([factory] if callable(factory) else factory):
            nodes.append(make())
        for node in nodes:
            if getattr(node, 'autostart', False):
                node.start()  # a managed node as a plain one: configured and active
        # what start-up made (modules, kernels, the model: some 150,000 objects) is kept out of
        # the collector's passes: a full collection walking it took 64 ms, two frames at 30
        # fps, whenever enough objects had survived since the last one
        gc.collect()
        gc.freeze()
        with _Profiled('+'.join(node.get_name() for node in nodes), 'main'):
            body(*nodes)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy.RCLError:
        # a signal shuts the context down while the executor builds its next wait set: rclpy
        # raises RCLError ('the given context is not valid') instead of
        # ExternalShutdownException (ros2/rclpy#398); after a shutdown that is a clean exit
        if rclpy.ok():
            raise
    except ParameterError as exc:
        rclpy.logging.get_logger('pose4d').fatal(str(exc))
        code = 2
    except InputFailure as exc:
        rclpy.logging.get_logger('pose4d').fatal(str(exc))
        code = 1
    finally:
        for node in nodes:  # every node's frames stop before any node is destroyed
            close_inputs(node)
        for node in nodes:
            close = getattr(node, 'close', None)
            if close is not None:
                close()
            node.destroy_node()
        try_shutdown()
    return code


def try_shutdown(context: rclpy.context.Context | None = None) -> None:
    """`rclpy.try_shutdown` of `context` (None: the default one), where a signal's shutdown of
    it (rclpy's signal handler thread) may land between its check and its call: rcl then
    refuses the second shutdown ('rcl_shutdown already called on the given context',
    ros2/rclpy#1352, fixed after Jazzy's rclpy by ros2/rclpy#1353), and the context is down
    all the same."""
    try:
        rclpy.try_shutdown(context=context)
    except _rclpy.RCLError:
        if rclpy.ok(context=context):
            raise


class StageMonitor:
    """Counts and times one stage's frames and publishes them as diagnostics.

    `frame(stamp_ns, processing_s)` after each processed frame; `dropped(n)` for frames skipped
    on purpose; `bad_input(text)` for refused input (logged, throttled, counted);
    `time_jumped(stamp_ns)` before a frame is processed: whether its stamp jumped back or more
    than `TIME_JUMP_S` forward (logged, counted as `time_jumps`), when the stage starts anew.
    Diagnostics
    are published on the wall clock (a paused sim clock does not silence them). Safe to call
    from a `FrameQueue`'s worker thread while the executor publishes.
    """

    def __init__(self, node: Node, stage: str, *, window: int = 300,
                 period_s: float = 1.0) -> None:
        self._node = node
        self.stage = stage
        self.frames = 0
        self.dropped_frames = 0
        self.bad_inputs = 0
        self.values: dict[str, object] = {}  # the stage's own figures (people in view, ...)
        self._jumps = StampJumps(TIME_JUMP_S)
        self._proc: deque[float] = deque(maxlen=window)
        self._latency: deque[float] = deque(maxlen=window)
        self._times: deque[float] = deque(maxlen=window)
        self._steps: deque[float] = deque(maxlen=window)
        self._last_stamp_ns: int | None = None
        self.clock_offset_s: float | None = None  # of the last frame, if from another clock
        self._clock_warned = False
        self._lock = threading.Lock()
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._timer = node.create_timer(period_s, self.publish,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def frame(self, stamp_ns: int, processing_s: float) -> None:
        with self._lock:
            self._frame(stamp_ns, processing_s)

    def _frame(self, stamp_ns: int, processing_s: float) -> None:
        self.frames += 1
        self._proc.append(processing_s)
        if self._last_stamp_ns is not None and stamp_ns > self._last_stamp_ns:
            self._steps.append((stamp_ns - self._last_stamp_ns) * 1e-9)
        self._last_stamp_ns = stamp_ns
        now_ns = self._node.get_clock().now().nanoseconds
        if now_ns == 0:  # sim time before the first /clock: no time to measure against
            return
        self._times.append(now_ns * 1e-9)
        latency = (now_ns - stamp_ns) * 1e-9
        if abs(latency) <= CLOCK_MISMATCH_S:
            self._latency.append(latency)
            self.clock_offset_s = None
            return
        self.clock_offset_s = latency
        if not self._clock_warned:
            self._clock_warned = True
            self._node.get_logger().warning(
                f'input stamps are {abs(latency):.0f} s {"behind" if latency > 0 else "ahead of"}'
                " this node's clock: they come from another clock (a bag replayed without "
                'use_sim_time? then set use_sim_time:=true here and replay.publish_clock:=true);'
                ' latency is not measured on such frames')

    def time_jumped(self, stamp_ns: int) -> bool:
        jump = self._jumps.jump_s(stamp_ns)
        if jump is not None:
            self.jumped(jump)
        return jump is not None

    def jumped(self, jump_s: float) -> None:
        """Say that the input stamps jumped by `jump_s` (negative: back) and the stage
        started anew (`time_jumped`, or a stage that checks its stamps itself: the
        `FramePipeline` of the pipeline node)."""
        self._node.get_logger().info(
            f'input stamps jumped {"back" if jump_s < 0 else "forward"} {abs(jump_s):.3f} s (a '
            'looping or restarted replay, a paused camera?): starting anew',
            throttle_duration_sec=5.0)

    def dropped(self, n: int = 1) -> None:
        self.dropped_frames += n

    def bad_input(self, text: str) -> None:
        self.bad_inputs += 1
        self._node.get_logger().warning(f'{text} ({self.bad_inputs} bad inputs so far)',
                                        throttle_duration_sec=5.0)

    def publish(self) -> None:
        with self._lock:
            times, proc, latency, steps = (list(d) for d in (
                self._times, self._proc, self._latency, self._steps))
        rate = 0.0
        if len(times) >= 2 and times[-1] > times[0]:
            rate = (len(times) - 1) / (times[-1] - times[0])
        values = {'frames': self.frames, 'dropped': self.dropped_frames,
                  'bad_inputs': self.bad_inputs, 'time_jumps': self._jumps.count,
                  'rate_hz': round(rate, 2), **self.values}
        for key, data in (('processing_ms', proc), ('latency_ms', latency),
                          ('time_step_ms', steps)):
            if data:
                p50, p95 = np.percentile(np.asarray(data) * 1e3, [50, 95])
                values[f'{key}_p50'] = round(float(p50), 2)
                values[f'{key}_p95'] = round(float(p95), 2)
        level = DiagnosticStatus.OK
        message = 'ok'
        if self.bad_inputs or self.dropped_frames:
            level = DiagnosticStatus.WARN
            message = f'{self.bad_inputs} bad inputs, {self.dropped_frames} dropped'
        if self.clock_offset_s is not None:
            values['clock_mismatch'] = (f'stamps {self.clock_offset_s:.1f} s from this node\'s '
                                        'clock (use_sim_time?)')
            level = DiagnosticStatus.WARN
            message = 'input stamps from another clock'
        status = DiagnosticStatus(
            level=level, name=f'pose4d: {self.stage}', message=message,
            hardware_id=self._node.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        try:
            self._pub.publish(DiagnosticArray(
                header=Header(stamp=self._node.get_clock().now().to_msg()), status=[status]))
        except _rclpy.RCLError:
            # Ctrl-C shuts the context down while the timer may still fire once: no clock
            # and no publisher any more, and nothing left to report to
            if self._node.context.ok():
                raise


def _header(sec: int, nanosec: int, frame_id: str) -> Header:
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def image_of_bytes(data: bytes) -> object:
    """A serialised `sensor_msgs/Image` read in place (`wire.image_from_cdr`: its pixels stay in
    the bytes until an array is made of them, its header an rclpy `Header`); bytes in another
    encapsulation, or that are no Image, are deserialised the general way (which says why
    it refuses them)."""
    try:
        return wire.image_from_cdr(data, _header)
    except ValueError:
        return deserialize_message(data, Image)


def subscribe(node: Node, msg_type: type, topic: str, callback: Callable[[object], None],
              profile: object, monitor: StageMonitor,
              decode: Callable[[bytes], object] | None = None) -> Subscription:
    """A subscription that counts the messages which do not deserialize as `msg_type`.

    It takes the serialized bytes (`raw=True`) and deserializes them here: rclpy's typed take
    drops such a message silently (no callback, nothing counted), so a broken driver's bytes
    would go unseen. Here each is counted as a bad input on `monitor` and warned about
    (throttled), and the next valid message is served as usual. An Image is read in place
    (`image_of_bytes`). (A 0-byte message never gets this far: Fast DDS drops it on arrival,
    which is why stage inputs are best effort, `qos.INPUT_QOS`.) `decode`: reads the bytes
    instead of `deserialize_message` (a ValueError for bytes it refuses); `callback` gets what
    it returns, unless None.
    """
    read = MessageReader(node, msg_type, topic, monitor, decode)

    def on_bytes(data: bytes) -> None:
        msg = read(data)
        if msg is not None:
            callback(msg)

    return node.create_subscription(msg_type, topic, on_bytes, profile, raw=True)


class MessageReader:
    """Reads one topic's serialised messages (`decode`, else an Image in place and other types
    by `deserialize_message`); bytes that hold no such message are counted as a bad input on
    `monitor`, named by topic and type, and read as None."""

    def __init__(self, node: Node, msg_type: type, topic: str, monitor: StageMonitor,
                 decode: Callable[[bytes], object] | None = None) -> None:
        self.name = node.resolve_topic_name(topic)
        self._kind = f'{msg_type.__module__.split(".")[0]}/{msg_type.__name__}'
        self._monitor = monitor
        self._decode = decode or (image_of_bytes if msg_type is Image
                                  else lambda data: deserialize_message(data, msg_type))

    def __call__(self, data: bytes) -> object | None:
        try:
            return self._decode(data)
        except Exception as exc:  # rclpy's RMWError: the CDR does not hold a msg_type
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._monitor.bad_input(
                f'{self.name}: {len(data)} bytes that are not a {self._kind} ({reason})')
            return None


# Frames a stage may hold waiting (`FrameQueue`, `PairedInputs`): a new track's first frames
# search every person scale (`ScaleConfig.warm_up_frames`, 3x the work), and the machine
# stalls now and then (the ros2 command line's queries), bursts that a queue of one turned into
# lost frames under load (`make test`, `pose4d demo --load busy`, `pose4d bench --graph --load
# query`: the foreground's drops, then, with two there, the IK's and tracker's); two absorb
# them, and latency stays bounded (at most two frames waiting)
STAGE_QUEUE = 2


class FrameQueue:
    """Frames processed in a worker thread, in arrival order, at most `size` waiting (1: the
    newest).

    `submit(item)` (in the executor's thread) queues `item`; when `size` frames already wait,
    the oldest is dropped and counted on the monitor. The worker thread processes them one at a
    time, so the executor keeps taking messages from DDS while a frame is processed: a stage
    slower than its input always works on the newest frame, drops the ones that came while it
    was busy, and latency stays bounded (about two processing times per stage) instead of
    building a backlog in its DDS reader queues. Dropped frames are not lost to the tracker,
    which predicts through them from the stamps. An unexpected error in `process` is logged
    (throttled) and counted as a bad input, and the queue goes on. `run` stops the worker
    (`close`) before the node is destroyed.
    """

    def __init__(self, node: Node, process: Callable[[object], None],
                 monitor: StageMonitor, size: int = STAGE_QUEUE) -> None:
        self._process = process
        self._monitor = monitor
        self._waiting: deque[object] = deque()
        self._size = size
        self._ready = threading.Condition()
        self._closed = False
        self._profiled = _Profiled(node.get_name(), f'{monitor.stage} frames')
        self._worker = threading.Thread(target=self._work, name=f'{monitor.stage} frames',
                                        daemon=True)
        # the node's queues, for `run` (and a lifecycle deactivation) to close
        self._queues = node.__dict__.setdefault('frame_queues', [])
        self._queues.append(self)
        self._worker.start()

    def submit(self, item: object) -> None:
        with self._ready:
            if len(self._waiting) >= self._size:
                self._waiting.popleft()
                self._monitor.dropped()
            self._waiting.append(item)
            self._ready.notify()

    def close(self) -> None:
        """Stop the worker after the frame in hand (frames still waiting are dropped)."""
        with self._ready:
            self._closed = True
            self._ready.notify()
        self._worker.join(timeout=10.0)
        if self in self._queues:
            self._queues.remove(self)

    def _work(self) -> None:
        with self._profiled:
            self._serve()

    def _serve(self) -> None:
        while True:
            with self._ready:
                while not self._waiting and not self._closed:
                    self._ready.wait()
                if self._closed:
                    return
                item = self._waiting.popleft()
            try:
                self._process(item)
            except Exception as exc:  # the live node keeps serving frames
                self._monitor.bad_input(f'frame failed: {type(exc).__name__}: {exc}')


class PairedInputs:
    """Subscribe to several topics, pair their messages by header stamp, process each set.

    The first topic is the pivot (colour); a set is complete when every topic has a message of
    the pivot's stamp (or the nearest within `slop_ns`, `core.sync.StampSync`). Complete sets go
    through a `FrameQueue`, so a slow `process` never builds a long backlog; unpaired
    messages and sets the queue had to drop are counted as dropped on the monitor.

    Parameters
    ----------
    topics : (message type, topic, QoS profile) per stream.
    process : called with the tuple of messages of one stamp.
    queue_size : complete sets that may wait (`FrameQueue`'s size).
    """

    def __init__(self, node: Node, topics: list[tuple[type, str, object]],
                 process: Callable[[tuple], None], monitor: StageMonitor, *,
                 slop_ns: int = 0, queue_size: int = STAGE_QUEUE) -> None:
        self._sync = StampSync(len(topics), slop_ns=slop_ns)
        self._monitor = monitor
        self._queue = FrameQueue(node, process, monitor, size=queue_size)
        for k, (kind, topic, profile) in enumerate(topics):
            if kind is not None:  # None: the caller pushes that stream (`push`)
                subscribe(node, kind, topic, lambda m, k=k: self._on(k, m), profile, monitor)

    def push(self, stream: int, msg: object) -> None:
        """A message of a stream the caller subscribed itself (anything with a `header`)."""
        self._on(stream, msg)

    def _on(self, stream: int, msg: object) -> None:
        before = self._sync.dropped[0]
        for _, items in self._sync.push(stream, stamp_to_ns(msg.header.stamp), msg):
            self._queue.submit(items)
        self._monitor.dropped(self._sync.dropped[0] - before)


class Closable(Protocol):
    """An input that stops when closed (`nodes.polled.PolledTopic`)."""

    def close(self) -> None: ...


def close_inputs(node: Node) -> None:
    """Stop a node's inputs: its frame queues (each finishes the frame in hand), then its
    polled topics, which those frames read."""
    for queue in list(node.__dict__.get('frame_queues', [])):
        queue.close()
    for topic in list(node.__dict__.get('polled_topics', [])):
        topic.close()


class SubscribedWhile:
    """A subscription that exists only while `wanted()` says it is needed: `wanted` is asked
    at start and every `period_s` on the steady clock (in the executor's thread), and the
    subscription made (`make()`: an rclpy `Subscription`, or what has a `close()`: a
    `nodes.polled.PolledTopic`) or destroyed when the answer changes. For inputs of outputs
    that are built on demand, and for a fallback input while its better source is missing: a
    message never taken costs nothing, while one received to be thrown away costs its
    transport and its bytes."""

    def __init__(self, node: Node, wanted: Callable[[], bool],
                 make: Callable[[], Subscription | Closable], *,
                 period_s: float = 0.5) -> None:
        self._node = node
        self._wanted = wanted
        self._make = make
        self.subscription: Subscription | Closable | None = None
        self.update()
        node.create_timer(period_s, self.update, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def update(self) -> None:
        want = self._wanted()
        if want and self.subscription is None:
            self.subscription = self._make()
        elif not want and self.subscription is not None:
            if isinstance(self.subscription, Subscription):
                self._node.destroy_subscription(self.subscription)
            else:
                self.subscription.close()
            self.subscription = None


class PeopleInputs:
    """The several-person input of a stage, with the single-person one beside it.

    Subscribes `people_topic` (pose4d_msgs/SkeletonArray: every person of a frame) and
    `single_topic` (JointArray: one person); with `extra` topics, each frame is paired by stamp
    with their messages (as `PairedInputs`). `process(people, header, extra_msgs)` gets a list
    of JointSets. The single-person topic is the fallback for an upstream stage that publishes
    only one person: it is subscribed only while nothing publishes the several-person topic
    (`SubscribedWhile`; our stages publish their single-person topic only while subscribed,
    so between two of ours each frame crosses once). A single-person message is taken as a
    list of one, unless a several-person message came in the last `PEOPLE_FRESH_S` seconds:
    then the upstream stage publishes both, and the single-person one (its primary person) is
    left out. A frame whose stamp was among the last few processed the other way is not
    processed again (both ways came in before the first several-person message did).

    Frames are processed in a `FrameQueue`'s worker, never in the executor's thread: a stage
    slower than its input works on the newest frame and drops the older ones (counted on the
    monitor, shown on /diagnostics) instead of letting them wait in its DDS reader queues.
    """

    PEOPLE_FRESH_S = 1.0

    def __init__(self, node: Node, people_topic: str, single_topic: str,
                 extra: list[tuple[type, str, object]],
                 process: Callable[[list, object, tuple], None], monitor: StageMonitor, *,
                 slop_ns: int = 0) -> None:
        self._process = process
        self._last_people = -float('inf')
        # (stamp, came as several people) of the last frames processed
        self._recent: deque[tuple[int, bool]] = deque(maxlen=4)
        self._monitor = monitor
        self._paired = (PairedInputs(node, [(None, people_topic, None), *extra],
                                     self._frame, monitor, slop_ns=slop_ns) if extra else None)
        self._queue = None if extra else FrameQueue(node, self._frame, monitor)

        def on_people(pivot: _Pivot) -> None:
            self._last_people = time.monotonic()
            self._pivot(pivot)

        def on_single(pivot: _Pivot) -> None:
            if time.monotonic() - self._last_people > self.PEOPLE_FRESH_S:
                self._pivot(pivot)

        subscribe(node, SkeletonArray, people_topic, on_people, qos.INPUT_QOS, monitor,
                  decode=lambda data: _Pivot.of_bytes(data, SkeletonArray))
        people_name = node.resolve_topic_name(people_topic)
        self.single = SubscribedWhile(
            node, lambda: node.count_publishers(people_name) == 0,
            lambda: subscribe(node, JointArray, single_topic, on_single, qos.INPUT_QOS, monitor,
                              decode=lambda data: _Pivot.of_bytes(data, JointArray)))

    def _pivot(self, pivot: _Pivot) -> None:
        if self._paired is not None:
            self._paired.push(0, pivot)
        else:
            self._queue.submit((pivot,))

    def _frame(self, items: tuple) -> None:
        header = items[0].header
        stamp, several = stamp_to_ns(header.stamp), items[0].several
        if (stamp, not several) in self._recent:
            # the frame came both ways (a restarted stage takes the single-person message
            # before it has seen the upstream's several-person one): it is processed once (a
            # frame sent again the same way is processed again)
            return
        self._recent.append((stamp, several))
        try:
            people = items[0].people()
        except ValueError as exc:
            self._monitor.bad_input(f'frame at {stamp} ns refused: {exc}')
            return
        self._process(people, header, items[1:])


class _Pivot:
    """A frame's header and its people (`people()`: read as they arrived, or, for a message
    deserialised the general way, when the frame is processed)."""

    def __init__(self, header: object, people: Callable[[], list], several: bool) -> None:
        self.header = header
        self.people = people
        self.several = several  # a SkeletonArray's (else a JointArray's: one person)

    @classmethod
    def of_bytes(cls, data: bytes, msg_type: type) -> _Pivot:
        """A serialised SkeletonArray's or JointArray's frame, read straight from the bytes
        (`wire.cdr`: a third of the CPU of deserialising the message and reading its
        fields) as it arrives, so that bytes which hold none are counted at once (ValueError);
        bytes in another encoding than little-endian CDR are deserialised the general way."""
        several = msg_type is SkeletonArray
        try:
            sec, nanosec, frame_id, at = wire.cdr_header(data)
        except ValueError:
            msg = deserialize_message(data, msg_type)
            return cls(msg.header, (lambda: list(wire.skeletons_from_msg(msg))) if several
                       else (lambda: [wire.joints_from_msg(msg)]), several)
        people = (list(wire.skeletons_from_cdr(data, at)) if several
                  else [wire.joints_from_cdr(data)])
        return cls(Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id),
                   lambda: people, several)


def pixel_pair(value: list) -> str | None:
    """The rule of `foreground.depth_shift_px` and `tracker.depth_shift_px`: two whole numbers
    of pixels."""
    if len(value) == 2 and all(isinstance(v, int) for v in value):
        return None
    return f'{list(value)}: give two whole numbers of pixels, [dx, dy]'


def camera_depth(msg: Image, shift: list[int]) -> np.ndarray:
    """The camera's depth image (metres), moved by `foreground.depth_shift_px` onto its
    colour image (`core.registration.shift_image`; as it is at [0, 0])."""
    depth = wire.depth_from_msg(msg)
    return shift_image(depth, *shift) if any(shift) else depth
