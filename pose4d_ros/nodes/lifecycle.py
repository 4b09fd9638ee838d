"""The managed node (the ROS 2 node lifecycle that Nav2's lifecycle manager and `ros2 lifecycle`
drive) that each stage node is, its machinery in one place.

`configure` loads and warms up the node's model and makes its publishers, `activate`
subscribes to its inputs, `deactivate` unsubscribes (an inactive node takes no message, so it
costs no CPU per frame while the camera plays, and keeps its model warm), `cleanup` drops the
model and the publishers, `shutdown` ends the node. Started plainly (`ros2 run`) a node
configures and activates itself (`lifecycle.autostart`, true by default: `common.run`); with
`lifecycle.autostart:=false` it waits unconfigured for a manager.

rclpy (Jazzy's 7.1.6) turns an exception in a transition callback into an ERROR without a word:
each step here logs why it failed.
"""

from __future__ import annotations

import gc
import traceback
from collections.abc import Callable

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node

from pose4d_ros.nodes.common import InputFailure, close_inputs
from pose4d_ros.nodes.params import NodeParams, Param, ParameterError

AUTOSTART = Param(
    'lifecycle.autostart', True, 'Configure and activate the node at start-up, as a plain '
    'node; false: it waits unconfigured for a lifecycle manager (ros2 lifecycle set <node> '
    'configure, then activate).', restart='it applies once, at start-up')


class _Made:
    """What a node had before a lifecycle step (its attributes, publishers, subscriptions and
    timers), to undo what the step made and whatever was made after it (a `SubscribedWhile`'s
    subscription, a REP 155 body's publishers)."""

    def __init__(self, node: Node) -> None:
        self.attributes = set(node.__dict__)
        self.publishers = set(node.publishers)
        self.subscriptions = set(node.subscriptions)
        self.timers = set(node.timers)

    def undo(self, node: Node, *, publishers: bool = True) -> None:
        """Destroy what was made since: timers first (no `SubscribedWhile` subscribes again),
        then subscriptions (no message is taken any more), then close the node's frame queues
        (each finishes the frame in hand) and its polled topics (`common.close_inputs`), then
        (with `publishers`) destroy the publishers; forget the attributes set since."""
        for timer in [t for t in node.timers if t not in self.timers]:
            node.destroy_timer(timer)
        for sub in [s for s in node.subscriptions if s not in self.subscriptions]:
            node.destroy_subscription(sub)
        close_inputs(node)
        for pub in [p for p in node.publishers if publishers and p not in self.publishers]:
            node.destroy_publisher(pub)
        for name in [n for n in node.__dict__ if n not in self.attributes]:
            delattr(node, name)


class ManagedNode(LifecycleNode):
    """A pose4d node under the ROS 2 node lifecycle (a managed node, `ros2 lifecycle`).

    A node class declares its parameters here (`params`, with `AUTOSTART` among them: they
    are declared at construction, so `ros2 param` works in every state) and implements two
    steps:

    - `configure(p)`: the expensive part, once: the model loaded and warmed up, the
      `StageMonitor`, the publishers;
    - `activate(p)`: the inputs: subscriptions, `FrameQueue`s, their timers.

    The rest is done here, the same for every node. `deactivate` destroys what `activate`
    made (and a `SubscribedWhile` made since) but the publishers: no message is taken, so an
    inactive node costs no CPU per frame while the camera plays, and keeps its model warm;
    the timers made by `configure` (the diagnostics) run only while active. `cleanup`
    destroys what `configure` made (publishers, including those made while active, such as
    the REP 155 bodies', and timers) and forgets the attributes it set (the model). `shutdown`
    undoes whatever is made and finalizes the node: `spin` then returns and the process exits.
    A step that fails is logged and leaves nothing behind: a refused setting (`ParameterError`,
    a model that does not load) fails the transition (the node stays where it was), another
    exception is an error, after which the node is unconfigured.

    `start()` configures and activates the node as a plain one does at start-up (`run` calls
    it when `lifecycle.autostart` is true, the default).
    """

    def __init__(self, name: str, params: tuple[Param, ...],
                 check: Callable[[dict], object] | None = None) -> None:
        super().__init__(name)
        self.params = NodeParams(self, params, check=check)
        self.autostart: bool = self.params.values[AUTOSTART.name]
        self.finalized = False
        self.failure: Exception | None = None  # why the last transition failed
        self._starting = False
        self._configured: _Made | None = None
        self._activated: _Made | None = None

    def configure(self, p: dict) -> None:
        """Load and warm up the model; make the monitor and the publishers."""
        raise NotImplementedError

    def activate(self, p: dict) -> None:
        """Subscribe to the inputs."""
        raise NotImplementedError

    def start(self) -> None:
        """Configure and activate, as a plain node starts; raises what made a step fail."""
        self._starting = True
        try:
            for step in (self.trigger_configure, self.trigger_activate):
                if step() != TransitionCallbackReturn.SUCCESS:
                    raise self.failure or RuntimeError('the lifecycle transition failed')
        finally:
            self._starting = False

    # rclpy's transition callbacks; rclpy turns an exception in them into an unlogged ERROR
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        def step() -> None:
            self._configured = _Made(self)
            self.configure(self.params.values)
            self._pause_timers()
            # what the model made is kept out of the collector's passes (`run`)
            gc.collect()
            gc.freeze()
        return self._transition('configure', step, self._cleanup)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        def step() -> None:
            self._activated = _Made(self)
            self.activate(self.params.values)
            self._resume_timers()
        return self._transition('activate', step, self._deactivate)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition('deactivate', self._deactivate)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition('cleanup', self._cleanup)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        def step() -> None:
            self._deactivate()
            self._cleanup()
            self.finalized = True
        return self._transition('shutdown', step)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        # back to unconfigured, with nothing of the failed step left
        self._deactivate()
        self._cleanup()
        return TransitionCallbackReturn.SUCCESS

    def _transition(self, name: str, step: Callable[[], None],
                    undo: Callable[[], None] | None = None) -> TransitionCallbackReturn:
        self.failure = None
        try:
            step()
        except (ParameterError, InputFailure) as exc:
            self.failure = exc
            if not self._starting:  # at start-up `run` says it (FATAL) and exits
                self.get_logger().error(f'{name} failed: {exc}')
            if undo is not None:
                undo()
            return TransitionCallbackReturn.FAILURE
        except Exception as exc:
            self.failure = exc
            if not self._starting:  # at start-up it goes on to `run` (a traceback)
                self.get_logger().error(f'{name} failed: {traceback.format_exc()}')
            return TransitionCallbackReturn.ERROR
        if not self._starting:
            self.get_logger().info(f'lifecycle: {name} done')
        return TransitionCallbackReturn.SUCCESS

    def _deactivate(self) -> None:
        if self._activated is not None:
            self._pause_timers()
            made, self._activated = self._activated, None
            made.undo(self, publishers=False)  # publishers belong to the configuration

    def _cleanup(self) -> None:
        if self._configured is not None:
            made, self._configured = self._configured, None
            made.undo(self)
            gc.unfreeze()  # the model goes: let the collector see it again
            gc.collect()

    def _pause_timers(self) -> None:
        """Stop the timers `configure` made (the diagnostics): none runs while inactive."""
        if self._configured is not None:
            for timer in self.timers:
                if timer not in self._configured.timers:
                    timer.cancel()

    def _resume_timers(self) -> None:
        if self._configured is not None:
            for timer in self.timers:
                if timer not in self._configured.timers and (
                        self._activated is None or timer in self._activated.timers):
                    timer.reset()
