"""What else a robot's computer does while the graph runs, as processes `run_graph` starts beside
it (`pose4d bench --graph --load ...`, `pose4d demo --load ...`):

- `busy`: a process that keeps one core busy (pure Python arithmetic, never sleeping), as a
  package install or a planner would;
- `query`: what a user at the ros2 command line does: `ros2 topic hz /pose4d/skeleton` (a
  subscriber that counts the skeletons and logs their rate every second) and, every second,
  `ros2 param get <node> use_sim_time` on each node of the graph (each a new DDS participant,
  as every `ros2 param` command is, that discovers the graph, calls the node's
  `get_parameters` service and leaves). The ros2 command line is not among the PyPI wheels;
  this does what its commands do, with rclpy.

Run as `python -m pose4d_ros.graph.load busy|query NODE...`; it runs until SIGINT or SIGTERM
and logs one line a second (what it did, and any call that got no answer).
"""

from __future__ import annotations

import os
import signal
import sys
import time

LOADS = ('busy', 'query')


def busy() -> None:
    """Keep one core busy until stopped."""
    x = 0
    while True:
        for i in range(100_000):
            x = (x * 31 + i) % 1_000_003


def param_get(node_name: str, timeout_s: float = 2.0) -> bool:
    """One `ros2 param get NODE use_sim_time`: a new participant, the service call, gone.
    True if the node answered within `timeout_s`."""
    import rclpy
    import rclpy.executors
    from rcl_interfaces.srv import GetParameters
    from rclpy.signals import SignalHandlerOptions

    from pose4d_ros.nodes.common import try_shutdown

    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        # a name of its own each time, as the ros2 command line's nodes have
        node = rclpy.create_node(f'pose4d_param_get_{os.getpid()}_{time.monotonic_ns()}',
                                 context=context)
        client = node.create_client(GetParameters, f'/{node_name}/get_parameters')
        if not client.wait_for_service(timeout_sec=timeout_s):
            return False
        future = client.call_async(GetParameters.Request(names=['use_sim_time']))
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        return future.done() and future.result() is not None
    finally:
        try_shutdown(context)  # a SIGINT may have shut it down already, or be doing so


def query(nodes: list[str]) -> None:
    """`ros2 topic hz /pose4d/skeleton` and a `ros2 param get` on each node every second."""
    import rclpy
    from pose4d_msgs.msg import JointArray
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('pose4d_topic_hz')
    count = 0

    def on_skeleton(_msg: object) -> None:
        nonlocal count
        count += 1

    node.create_subscription(JointArray, 'pose4d/skeleton', on_skeleton, qos_profile_sensor_data)
    start = last = time.monotonic()
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.05)
        now = time.monotonic()
        if now - last >= 1.0:
            answered = [name for name in nodes if param_get(name)]
            print(f'{now - start:6.1f} s: {count} skeletons ({count / (now - start):.1f} Hz); '
                  f'param get answered by {len(answered)} of {len(nodes)} nodes'
                  + (f' (not {", ".join(sorted(set(nodes) - set(answered)))})'
                     if len(answered) < len(nodes) else ''), flush=True)
            last = time.monotonic()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in LOADS:
        print(f'usage: python -m pose4d_ros.graph.load {"|".join(LOADS)} [NODE...]',
              file=sys.stderr)
        return 2
    # the only handlers (rclpy's are off: SIGTERM shut its contexts down while a `ros2 param
    # get` made its node, an RCLError and exit status 1 where the load was only stopped)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        busy() if argv[0] == 'busy' else query(argv[1:])
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == '__main__':
    sys.exit(main())
