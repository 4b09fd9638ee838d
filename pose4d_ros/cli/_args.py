"""Argument types several verbs share."""

from __future__ import annotations

import argparse


def factor_list(text: str) -> tuple[float, ...]:
    """argparse type: '0.87,1,1.15' -> (0.87, 1.0, 1.15)."""
    try:
        return tuple(float(v) for v in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a comma list of numbers') from None
