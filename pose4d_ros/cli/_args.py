"""Argument types several verbs share."""

from __future__ import annotations

import argparse


def factor_list(text: str) -> tuple[float, ...]:
    """argparse type: '0.87,1,1.15' -> (0.87, 1.0, 1.15)."""
    try:
        return tuple(float(v) for v in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a comma list of numbers') from None


def load_list(text: str) -> tuple[str, ...]:
    """argparse type: 'busy,query' -> ('busy', 'query'), each one of `graph.load.LOADS`."""
    from pose4d_ros.graph.load import LOADS

    kinds = tuple(k for k in text.split(',') if k)
    if not set(kinds) <= set(LOADS):
        raise argparse.ArgumentTypeError(f'{text!r}: expected a comma list of {", ".join(LOADS)}')
    return kinds
