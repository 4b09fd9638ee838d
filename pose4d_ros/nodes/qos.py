"""Quality-of-service profiles of the node graph.

- Camera inputs: the sensor-data profile (best effort, keep last 5). A best-effort subscription
  matches both reliable and best-effort publishers, so any driver (or the bag replay) connects.
- Stage inputs from other stages (the parts a detector or tracker sends): best effort, keep
  last 10. A best-effort subscription matches our reliable outputs too, and no sample can stall
  it: a reliable reader waits for every sample of a writer in order, and a sample the middleware
  cannot take (Fast DDS drops a 0-byte serialized message on arrival) is asked for again and
  again, so the reader never delivers another message of that writer (measured: a tracker
  whose reliable input got one 0-byte `JointArray` answered none of the valid ones after it,
  whatever the executor, raw or typed; `test/test_wedge.py`). Between processes of one machine
  (shared memory) a best-effort reader loses nothing its queue holds.
- Camera images read beside a frame (the tracker's depth): best effort, keep last 8.
- Our outputs: reliable, keep last 10.
- /tf: reliable, keep last 100 (tf2_ros's broadcaster profile).
- Bags: the QoS a topic was recorded with is offered again on replay.
"""

from __future__ import annotations

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

SENSOR_QOS: QoSProfile = qos_profile_sensor_data
INPUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
OUTPUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
# camera images a stage reads beside its frame, if they have come (`polled.RecentImages`): the
# sensor-data profile's best effort, the last 8 kept
RECENT_QOS = QoSProfile(depth=8, reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)

def _duration(t: object) -> Duration | None:
    sec, nsec = int(t.sec), int(t.nsec)
    if sec >= 0x7FFFFFFF or (sec == 0 and nsec == 0):
        return None  # infinite / default
    return Duration(seconds=sec, nanoseconds=nsec)


def from_bag(qos: object) -> QoSProfile:
    """rclpy profile from a rosbags `Qos` recorded in a bag's metadata."""
    rel = ReliabilityPolicy.BEST_EFFORT if qos.reliability.name == 'BEST_EFFORT' \
        else ReliabilityPolicy.RELIABLE
    dur = DurabilityPolicy.TRANSIENT_LOCAL if qos.durability.name == 'TRANSIENT_LOCAL' \
        else DurabilityPolicy.VOLATILE
    hist = HistoryPolicy.KEEP_ALL if qos.history.name == 'KEEP_ALL' else HistoryPolicy.KEEP_LAST
    profile = QoSProfile(depth=max(int(qos.depth), 1), reliability=rel, durability=dur,
                         history=hist, liveliness=LivelinessPolicy.AUTOMATIC)
    for attr in ('deadline', 'lifespan'):
        value = _duration(getattr(qos, attr))
        if value is not None:
            setattr(profile, attr, value)
    return profile


def matching_subscription(publisher_profiles: list[QoSProfile], depth: int = 100) -> QoSProfile:
    """A subscription profile that connects to every given publisher without losing messages.

    Like `ros2 bag record`: reliable only if every publisher is reliable (a reliable
    subscription would not match a best-effort publisher), transient-local only if all are.
    """
    reliable = bool(publisher_profiles) and all(
        p.reliability == ReliabilityPolicy.RELIABLE for p in publisher_profiles)
    latched = bool(publisher_profiles) and all(
        p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publisher_profiles)
    return QoSProfile(
        depth=depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )
