"""Summaries of per-frame timings, shared by the benchmarks."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def ms_stats(ms: Iterable[float]) -> dict[str, float | None]:
    """p50 and p95 of per-frame times in ms (None for none)."""
    a = np.asarray(list(ms), np.float64)
    if not a.size:
        return {'p50': None, 'p95': None}
    return {'p50': round(float(np.percentile(a, 50)), 3),
            'p95': round(float(np.percentile(a, 95)), 3)}
