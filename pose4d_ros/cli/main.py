"""Entry point of the `pose4d` command.

Each verb lives in its own module under `pose4d_ros.cli` and exposes `add_parser(subparsers)`
(which registers the verb and sets `func`) and the function it runs. Errors that a user can fix
(a bad file, a bad value) are raised as `ValueError`/`OSError`, printed as one line naming the
file or value, and end the command with exit status 2 (1 for anything unexpected).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from pose4d_ros import __version__

# Verb modules, in the order `pose4d --help` lists them.
VERBS = ('synth', 'cad60_to_bag', 'train', 'train_convnet', 'quantize_convnet', 'eval', 'bench',
         'demo', 'track_eval', 'bag_repair', 'results')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='pose4d',
        description='pose4d_ros offline tools: make data, train, evaluate, benchmark, demo.',
    )
    parser.add_argument('--version', action='version', version=f'pose4d {__version__}')
    parser.add_argument('--debug', action='store_true',
                        help='on an error, show the whole traceback, not only its one line')
    subparsers = parser.add_subparsers(dest='verb', metavar='VERB')
    for verb in VERBS:
        try:
            module = importlib.import_module(f'pose4d_ros.cli.{verb}')
        except ModuleNotFoundError as exc:
            if exc.name != f'pose4d_ros.cli.{verb}':
                raise
            continue  # verb not part of this version
        module.add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.verb is None:
        parser.print_help()
        return 0
    from pose4d_ros.core.malloc import keep_freed_memory
    from pose4d_ros.core.threads import set_blas_threads

    keep_freed_memory()  # the heap the nodes run with (core.malloc)
    set_blas_threads(1)  # one BLAS thread: the measured best on 2 shared cores (a verb may
    # choose otherwise, e.g. `pose4d bench --blas-threads`)
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f'pose4d {args.verb}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'pose4d {args.verb}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
