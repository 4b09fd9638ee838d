"""`pose4d bag-repair PARTIAL [--out BAG]`: a recording a crash left unfinished -> a bag."""

from __future__ import annotations

import argparse
from pathlib import Path

from pose4d_ros.datasets import bag


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'bag-repair', help='recover the messages of an unfinished recording',
        description='Turn what a recorder killed before it closed its bag left behind (the '
        'hidden .NAME.partial-PID directory beside its output, or the .mcap/.db3 in it) into '
        'a readable bag: every message it had put on disk (every flush, 0.5 s by default). '
        'Without --out the bag gets the recording\'s name; the partial recording is removed '
        'once the bag is in place (--keep keeps it).')
    p.add_argument('partial', type=Path, help='the unfinished recording')
    p.add_argument('--out', type=Path, help='new bag directory (must not exist)')
    p.add_argument('--keep', action='store_true', help='keep the partial recording')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    result = bag.repair(args.partial, args.out)
    total = sum(result.counts.values())
    counts = ', '.join(f'{t} {n}' for t, n in result.counts.items()) or 'no topic'
    print(f'recovered {total} messages into {result.path} ({counts})'
          + (f'; skipped {result.skipped}' if result.skipped else ''))
    removed = None if args.keep else bag.remove_partial(args.partial)
    if removed is not None:
        print(f'removed the partial recording {removed}')
    return 0
