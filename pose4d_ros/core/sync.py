"""Pairing of image streams by capture stamp (colour with depth, a stage's outputs together).

Never "the latest depth": a colour frame is paired with the depth frame of the same stamp, or,
when `slop_ns` > 0, with the one nearest in time within the slop (drivers that stamp the two
streams separately). Stream 0 is the pivot (colour): each of its frames is emitted at most once,
in stamp order, with one item of every other stream. A pivot frame that cannot be matched any
more (the other streams have moved past it) is dropped and counted, and so are the other
streams' items that no pivot claimed.
"""

from __future__ import annotations

from collections import deque
from typing import Any


class StampSync:
    """Match items of `n_streams` streams by stamp.

    Parameters
    ----------
    n_streams : number of streams (>= 2); stream 0 is the pivot.
    slop_ns : largest allowed stamp difference to the pivot, nanoseconds (0 = exact).
    queue_size : items kept per stream while waiting; older ones are dropped.

    Attributes
    ----------
    dropped : per stream, items discarded without being emitted.
    """

    def __init__(self, n_streams: int, *, slop_ns: int = 0, queue_size: int = 10) -> None:
        if n_streams < 2:
            raise ValueError(f'n_streams must be >= 2, got {n_streams}')
        if slop_ns < 0:
            raise ValueError(f'slop_ns must be >= 0, got {slop_ns}')
        if queue_size < 1:
            raise ValueError(f'queue_size must be >= 1, got {queue_size}')
        self.slop_ns = int(slop_ns)
        self.queues: list[deque[tuple[int, Any]]] = [deque() for _ in range(n_streams)]
        self.latest = [-1] * n_streams
        self.dropped = [0] * n_streams
        self.queue_size = queue_size

    def push(self, stream: int, stamp_ns: int, item: Any) -> list[tuple[int, tuple[Any, ...]]]:
        """Add one item; return the matched sets now complete: [(pivot stamp, items), ...].

        Items of a stream must come in stamp order; one that does not (a bag replayed again,
        a driver restart) resets that stream's queue.
        """
        q = self.queues[stream]
        if stamp_ns <= self.latest[stream]:
            self.dropped[stream] += len(q)
            q.clear()
        self.latest[stream] = stamp_ns
        q.append((stamp_ns, item))
        if len(q) > self.queue_size:
            q.popleft()
            self.dropped[stream] += 1
        return self._match()

    def _match(self) -> list[tuple[int, tuple[Any, ...]]]:
        out = []
        pivots = self.queues[0]
        while pivots:
            stamp, pivot_item = pivots[0]
            chosen: list[int] = []
            waiting = False
            impossible = False
            for q, latest in zip(self.queues[1:], self.latest[1:], strict=True):
                best, best_d = -1, None
                for i, (s, _) in enumerate(q):
                    d = abs(s - stamp)
                    if d <= self.slop_ns and (best_d is None or d < best_d):
                        best, best_d = i, d
                # Items come in stamp order: once a stream has reached the pivot's stamp no
                # later item can be nearer; before that, one still may (or the exact one).
                if latest < stamp:
                    waiting = True
                elif best < 0:
                    impossible = True
                chosen.append(best)
            if impossible:
                pivots.popleft()
                self.dropped[0] += 1
                continue
            if waiting:
                break
            pivots.popleft()
            items = [pivot_item]
            for q, k, stream in zip(self.queues[1:], chosen, range(1, len(self.queues)),
                                    strict=True):
                self.dropped[stream] += k  # items older than the match are never used
                for _ in range(k):
                    q.popleft()
                items.append(q.popleft()[1])
            out.append((stamp, tuple(items)))
        return out


# Stamps that go back, or forward by more than this, seconds: the stages start anew (the nodes'
# `StageMonitor.time_jumped`, the several-person `FramePipeline`)
TIME_JUMP_S = 1.0


class StampJumps:
    """Tells when a stream's stamps jump: back in time (a looping replay, a restarted driver or
    bag) or forward by more than `max_gap_s` (a paused replay, a camera that was away).

    What a stage remembers of earlier frames (a track, a person's scale, learned bone lengths, a
    held mask) belongs to the time before the jump: the stage starts anew on such a frame.
    """

    def __init__(self, max_gap_s: float = 1.0) -> None:
        if not max_gap_s > 0:
            raise ValueError(f'max_gap_s must be > 0, got {max_gap_s}')
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.last_ns: int | None = None
        self.count = 0

    def jump_s(self, stamp_ns: int) -> float | None:
        """The jump from the previous stamp to `stamp_ns`, seconds (negative: back), or None
        when there is none (the first stamp, a repeated one, a step within the gap)."""
        last, self.last_ns = self.last_ns, stamp_ns
        if last is None or 0 <= stamp_ns - last <= self.max_gap_ns:
            return None
        self.count += 1
        return (stamp_ns - last) * 1e-9
