"""The four stage nodes composed in one process (`ros2 run pose4d_ros composed`): foreground,
detector, tracker and ik, each the node that `ros2 run pose4d_ros <stage>` starts (its name,
parameters, topics, lifecycle services and /diagnostics), served by one executor.

Between processes each frame crosses Fast DDS's shared memory three times, and each process
pays its own executor and DDS threads and runs its stage on caches the others have evicted:
composed, the four cost a fifth less CPU a frame than as four processes (11.7 against 14.7
ms on bench300, `docs/results/bench_graph300_quiet.json`). Run the stages apart to spread
them over hosts or restart one alone; the one-process `pipeline` node is cheaper still, but
it is one node, not four.

Parameters are given as to the stage nodes (`--ros-args -p detector.model:=rgbd_14`): each
name is its stage's, so each node takes its own; so are their parameter files, one
`--params-file` each (config/foreground.yaml, detector.yaml, tracker.yaml, ik.yaml).
"""

from __future__ import annotations

from pose4d_ros.nodes.common import run
from pose4d_ros.nodes.detector import DetectorNode
from pose4d_ros.nodes.foreground import ForegroundNode
from pose4d_ros.nodes.ik import IkNode
from pose4d_ros.nodes.tracker import TrackerNode

NODES = (ForegroundNode, DetectorNode, TrackerNode, IkNode)


def main(args: list[str] | None = None) -> int:
    return run(NODES, args)
