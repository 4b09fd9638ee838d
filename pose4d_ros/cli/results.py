"""`pose4d results`: every set, table and figure the READMEs report, from one command.

    pose4d results [--only JOB[,JOB...]] [--utkinect DIR] [--msraction3d DIR] [--lspet DIR]
                   [--no-peer]

Makes the protocol's sets (`pose4d synth`, into data/synth/, reusing a set made by the same
command), runs `pose4d eval` and `pose4d bench` for every table (with `--peer mediapipe` when
`make peer` has made .venv-peer; without it, the peer's rows and the job that fits its depth
offsets are skipped and said so), and writes docs/results/*.json, docs/results/index.json (the
commands, the machine, the commit, what was skipped), the generated docs/RESULTS.md and the
README's summary (`evaluation.results`, the sets and jobs in `evaluation.results_jobs`,
`evaluation.results_doc`). Run from the repository root. Jobs, in order: see `--help`
(`--only`).
"""

from __future__ import annotations

import argparse

from pose4d_ros.evaluation import results


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        'results', help='every table and figure of the READMEs, from one command',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('--only', type=lambda s: s.split(','), default=None, metavar='JOB,...',
                   help=f'run only these jobs ({", ".join(results.JOB_NAMES)})')
    p.add_argument('--utkinect', default='../shared/data/utkinect',
                   help='UTKinect motion, for the rendered sets')
    p.add_argument('--msraction3d', default=results.MSRACTION3D,
                   help='MSR Action3D motion, for the rendered sets posed by it')
    p.add_argument('--lspet', default='../shared/data/lspet', help='LSPET root')
    p.add_argument('--no-peer', action='store_true', help='do not run MediaPipe')
    p.add_argument('--parallel', type=int, default=1, metavar='N',
                   help="run N of a validation job's evaluations side by side (their "
                        'accuracies and search work do not depend on it; timings would)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.parallel < 1:
        raise ValueError(f'--parallel {args.parallel}: must be at least 1')
    unknown = [j for j in args.only or () if j not in results.JOB_NAMES]
    if unknown:
        raise ValueError(f'--only {",".join(unknown)}: no such job (jobs: '
                         f'{", ".join(results.JOB_NAMES)})')
    index = results.run(args.only, utkinect=args.utkinect, lspet=args.lspet,
                        peer=False if args.no_peer else None, msraction3d=args.msraction3d,
                        parallel=args.parallel)
    skipped = index['last_run']['skipped']
    print(f"ran {len(index['last_run']['jobs']) - len(skipped)} job(s), skipped "
          f"{len(skipped)}" + ''.join(f"\n  {s['job']}: {s['why']}" for s in skipped))
    print('wrote docs/results/, docs/RESULTS.md and the README summary')
    return 0
