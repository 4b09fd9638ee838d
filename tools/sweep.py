"""Where the tracker holds: a sweep over body height, distance and view, ours against the peer.

    .venv/bin/python tools/sweep.py --utkinect ../shared/data/utkinect --out out/sweep \
        [--statures 1.4,1.7,2.0] [--distances 1.2,2.5,4.5] [--turns 0,45,90] [--frames 30]

Each cell renders `--frames` 30 fps frames of held-out motion (UTKinect s07_e01, two windows of
a take) with bodies of that height at that distance, turned that far (`pose4d synth
--stature H H --distance D D --turn T T`), then scores them with `pose4d eval --peer mediapipe`
(the nodes' model, `rgbd_kf_ik`, against MediaPipe on the same frames). Writes
`OUT/sweep.json` and prints a Markdown table: PCK@0.1 average7 and the share of joints within
10 cm in 3-D, ours / MediaPipe's, per cell.
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
from pathlib import Path

BIN = Path(sys.executable).parent


def factors(text: str) -> list[float]:
    return [float(x) for x in text.split(',') if x]


def run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f'{" ".join(cmd)} failed:\n{done.stderr[-2000:]}')


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--utkinect', required=True)
    p.add_argument('--out', type=Path, required=True)
    p.add_argument('--statures', type=factors, default=[1.4, 1.7, 2.0])
    p.add_argument('--distances', type=factors, default=[1.2, 2.5, 4.5])
    p.add_argument('--turns', type=factors, default=[0.0, 45.0, 90.0])
    p.add_argument('--frames', type=int, default=30)
    args = p.parse_args(argv)
    pose4d = str(BIN / 'pose4d')
    args.out.mkdir(parents=True, exist_ok=True)
    cells = {}
    for k, (h, d, t) in enumerate(itertools.product(args.statures, args.distances, args.turns)):
        name = f'h{h:g}_d{d:g}_t{t:g}'
        data = args.out / name
        if not data.is_dir():
            run([pose4d, 'synth', '--utkinect', args.utkinect, '--out', str(data),
                 '--seed', str(100 + k), '--takes', 's07_e01', '--videos-per-take', '2',
                 '--frames', str(args.frames // 2), '--start', '20', '--stature', str(h), str(h),
                 '--distance', str(d), str(d), '--turn', str(t), str(t), '--quiet'])
        table = args.out / f'{name}.json'
        run([pose4d, 'eval', str(data), '--json', str(table), '--peer', 'mediapipe',
             '--model', 'rgbd_14'])
        rows = json.loads(table.read_text())['rows']
        cells[name] = {'stature_m': h, 'distance_m': d, 'turn_deg': t, **{
            row: {'pck_average7': rows[row]['pck']['average7'],
                  'within_10cm': rows[row].get('within_10cm', {}).get('average')}
            for row in ('rgbd_kf_ik', 'mediapipe')}}
        print(name, cells[name], flush=True)
    (args.out / 'sweep.json').write_text(json.dumps(cells, indent=1) + '\n')
    print(markdown(cells, args))
    return 0


def markdown(cells: dict, args: argparse.Namespace) -> str:
    def fmt(v: float | None) -> str:
        return '-' if v is None else f'{v:.0f}'

    head = '| height, distance | ' + ' | '.join(f'{t:g} deg' for t in args.turns) + ' |'
    lines = [head, '|---' * (len(args.turns) + 1) + '|']
    for h, d in itertools.product(args.statures, args.distances):
        out = []
        for t in args.turns:
            c = cells[f'h{h:g}_d{d:g}_t{t:g}']
            ours, peer = c['rgbd_kf_ik'], c['mediapipe']
            out.append(f"{fmt(ours['pck_average7'])} / {fmt(peer['pck_average7'])} PCK, "
                       f"{fmt(ours['within_10cm'])} / {fmt(peer['within_10cm'])} 3-D")
        lines.append(f'| {h:g} m, {d:g} m | ' + ' | '.join(out) + ' |')
    return '\n'.join(lines)


if __name__ == '__main__':
    sys.exit(main())
