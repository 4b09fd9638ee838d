"""Every figure the READMEs report, from one command (`pose4d results`, `make results`).

The protocol (`pose4d_ros/models/README.md`, first section): training, validation and test sets
are disjoint by subject and seed; settings are chosen on validation sets; the test sets are run
once per shipped model, to report. `evaluation.results_jobs` holds that protocol's sets (`SETS`:
each a `pose4d synth` command, made into `data/synth/NAME` unless a set made by the same command
is there) and its jobs (`JOBS`: `pose4d eval` and `pose4d bench` commands, each writing JSON
under `docs/results/`); this module runs them as the user would type them (subprocesses of the
`pose4d` beside this Python, their progress lines passed through), chooses each validation
sweep's value from their tables (`summarize_validation`, `summarize_colour_net`,
`choose_label`), and writes `docs/results/index.json` (per job: the commands, when, how long,
done or skipped and why; the machine; the commit) and the generated `docs/RESULTS.md` and README
summary (`evaluation.results_doc`). The names of `results_jobs` are importable from here too,
but for its folders (`RESULTS`, `DATA`, `WORK`), which are read there alone.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from pose4d_ros.core.files import write_json
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.people import TrackingConfig
from pose4d_ros.evaluation import results_jobs
from pose4d_ros.evaluation.results_jobs import (
    ARMS,
    COLOUR_NET,
    COLOUR_NET_GRID,
    COLOUR_NET_RENDERS,
    COLOUR_NET_RGBD_LOSS,
    COLOUR_NET_TESTS,
    COLOUR_NET_VALID,
    DEFAULT_MARGIN,
    JOB_NAMES,
    JOBS,
    LSPET,
    MARGINS,
    MAX_CPU_INCREASE,
    MIN_SEARCH_SAVING,
    MSR_ACTIONS,
    MSRACTION3D,
    PEOPLE_SETS,
    PEOPLE_SWEEP_SETS,
    PEOPLE_TESTS,
    REAL,
    REAL_SETS,
    REAL_VARIANTS,
    SETS,
    SHIPPED_RUNS,
    STAMP,
    SWEEP_SETS,
    SWEEPS,
    TIE,
    UTKINECT,
    Context,
    DataSet,
    Job,
    chosen_colour_net,
    colour_net_file,
    sweep_file,
    sweep_sets,
)
from pose4d_ros.peer import peer_python
from pose4d_ros.util.machine import git_commit, machine
from pose4d_ros.util.progress import log

__all__ = [
    'ARMS',
    'COLOUR_NET',
    'COLOUR_NET_GRID',
    'COLOUR_NET_RENDERS',
    'COLOUR_NET_RGBD_LOSS',
    'COLOUR_NET_TESTS',
    'COLOUR_NET_VALID',
    'DEFAULT_MARGIN',
    'GROUPS7',
    'IDF1_TIE',
    'JOBS',
    'JOB_NAMES',
    'LSPET',
    'MARGINS',
    'MAX_CPU_INCREASE',
    'MAX_FALSE_INCREASE',
    'MIN_SEARCH_SAVING',
    'MOTION_REVISION',
    'MSRACTION3D',
    'MSR_ACTIONS',
    'PEOPLE_SETS',
    'PEOPLE_SWEEP_SETS',
    'PEOPLE_TESTS',
    'REAL',
    'REAL_SETS',
    'REAL_VARIANTS',
    'SETS',
    'SHIPPED_RUNS',
    'STAMP',
    'SWEEPS',
    'SWEEP_SETS',
    'TIE',
    'TRACKING_KEYS',
    'UTKINECT',
    'Context',
    'DataSet',
    'Job',
    'choose_label',
    'chosen_colour_net',
    'colour_net_file',
    'make_set',
    'peer_available',
    'pose4d_executable',
    'run',
    'summarize_colour_net',
    'summarize_people',
    'summarize_validation',
    'sweep_file',
    'sweep_sets',
    'tracks_worse',
]


def pose4d_executable() -> str:
    """The `pose4d` of this Python's environment."""
    exe = Path(sys.executable).parent / 'pose4d'
    return str(exe) if exe.exists() else 'pose4d'


def _run_all(cmds: Sequence[Sequence[str]], parallel: int = 1) -> None:
    """Run the commands, `parallel` at a time (each in its own process); RuntimeError naming
    the first that failed."""
    if parallel <= 1:
        for c in cmds:
            _run(c)
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(parallel) as pool:
        for future in [pool.submit(_run, c) for c in cmds]:
            future.result()


def _run(cmd: Sequence[str]) -> float:
    """Run a `pose4d ...` command (or another program's), its output passed through; its wall
    time, seconds. RuntimeError when it fails."""
    log('$ ' + shlex.join(cmd))
    t0 = time.monotonic()
    argv = [pose4d_executable(), *cmd[1:]] if cmd[0] == 'pose4d' else list(cmd)
    done = subprocess.run(argv, check=False)
    if done.returncode != 0:
        raise RuntimeError(f'{shlex.join(cmd)}: exit status {done.returncode}')
    return time.monotonic() - t0


# What a set's renders depend on beyond its command (its stamp's comment): a set made before
# a change of its motion's reading is made again
MOTION_REVISION = {'msraction3d': '  # legs repaired (datasets.msraction3d.repair_legs)'}


def make_set(ds: DataSet, utkinect: str = UTKINECT, msraction3d: str = MSRACTION3D) -> str:
    """Make `ds` unless a set made by the same command (and motion revision) is there; what
    was done."""
    cmd = ds.command(utkinect, msraction3d)
    made_by = shlex.join(cmd) + MOTION_REVISION.get(ds.motion, '')
    out = results_jobs.DATA / ds.name
    stamp = out / STAMP
    if stamp.exists() and stamp.read_text().strip() == made_by:
        return 'reused'
    import shutil
    made = [out, out.with_name(out.name + '_bag')] if ds.bag else [out]
    for path in made:
        if path.exists():
            shutil.rmtree(path)
    _run(cmd)
    if ds.bag:
        _run(['pose4d', 'cad60-to-bag', str(out), str(made[1])])
    stamp.write_text(made_by + '\n')
    return 'made'


def peer_available() -> bool:
    """MediaPipe is there: `make peer` finished (its stamp), or $POSE4D_PEER_PYTHON is set."""
    import os

    python = peer_python()
    return python.exists() and (bool(os.environ.get('POSE4D_PEER_PYTHON'))
                                or (python.parent.parent / '.stamp').exists())


def run(only: Sequence[str] | None = None, *, utkinect: str = UTKINECT, lspet: str = LSPET,
        peer: bool | None = None, msraction3d: str = MSRACTION3D, parallel: int = 1) -> dict:
    """Run the jobs (`only`: those named, in `JOBS` order), write their JSON, the index,
    `docs/RESULTS.md` and the README summary; the index. `parallel`: how many of a job's
    commands run side by side where the job allows it (`Job.parallel`)."""
    from pose4d_ros.evaluation import results_doc

    selected = [j for j in JOBS if only is None or j.name in only]
    ctx = Context(utkinect, lspet, peer_available() if peer is None else peer,
                  msraction3d=msraction3d)
    for d in (results_jobs.RESULTS, results_jobs.WORK, results_jobs.DATA):
        d.mkdir(parents=True, exist_ok=True)
    index_path = results_jobs.RESULTS / 'index.json'
    index = json.loads(index_path.read_text()) if index_path.exists() else {}
    jobs = index.get('jobs', {})
    # each job says the machine it last ran on; an index written before that said one machine,
    # the last run's, for every job then
    for entry in jobs.values():
        if 'commands' in entry and 'machine' not in entry and 'machine' in index:
            entry['machine'] = index['machine'].get('cpu', '?')
    run_skipped = []
    for n, job in enumerate(selected, 1):
        log(f'[{n}/{len(selected)}] {job.name}: {job.what}')
        reason = _missing(job, ctx)
        if reason:
            log(f'{job.name}: skipped ({reason})')
            run_skipped.append({'job': job.name, 'why': reason})
            jobs[job.name] = {**jobs.get(job.name, {}), 'what': job.what,
                              'skipped_last_run': reason}
            continue
        t0 = time.monotonic()
        commands = [shlex.join(c) for c in job.commands(ctx)]
        try:
            sets = {s: make_set(SETS[s], utkinect, msraction3d) for s in job.sets}
            _run_all(job.commands(ctx), parallel if job.parallel else 1)
            if job.name == 'validation':
                write_json(results_jobs.RESULTS / 'validation.json', summarize_validation(),
                           indent=1)
            if job.name == 'colour_net':
                write_json(results_jobs.RESULTS / 'colour_net.json', summarize_colour_net(),
                           indent=1)
        except (RuntimeError, OSError, ValueError, KeyError) as e:
            log(f'{job.name}: failed ({e})')
            run_skipped.append({'job': job.name, 'why': f'failed: {e}'})
            jobs[job.name] = {**jobs.get(job.name, {}), 'what': job.what,
                              'skipped_last_run': f'failed: {e}'}
            continue
        jobs[job.name] = {
            'what': job.what, 'sets': {s: shlex.join(ctx.set_command(s)) for s in sets},
            'commands': commands, 'seconds': round(time.monotonic() - t0, 1),
            'when': time.strftime('%Y-%m-%d %H:%M:%S'), 'commit': git_commit(),
            'machine': str(machine().get('cpu', '?')),
            'peer': ctx.peer and (job.needs_peer or 'mediapipe' in ' '.join(commands)),
        }
        if job.parallel and parallel > 1:
            jobs[job.name]['note'] = f'its commands run {parallel} at a time'
        if not ctx.peer and not job.needs_peer and any(
                c[1] in ('eval', 'bench') for c in job.commands(ctx)):
            jobs[job.name]['note'] = 'run without the peer (no .venv-peer: `make peer`)'
    index = {'machine': machine(), 'commit': git_commit(), 'jobs': jobs,
             'sets': {k: {'role': v.role, 'command': shlex.join(ctx.set_command(k))}
                      for k, v in SETS.items()},
             'last_run': {'jobs': [j.name for j in selected], 'skipped': run_skipped,
                          'when': time.strftime('%Y-%m-%d %H:%M:%S')}}
    write_json(index_path, index, indent=1)
    results_doc.write_all(results_jobs.RESULTS, index)
    for s in run_skipped:
        log(f"skipped {s['job']}: {s['why']}")
    return index


def _missing(job: Job, ctx: Context) -> str:
    """Why the job cannot run here ('' if it can)."""
    if job.needs_peer and not ctx.peer:
        return f'needs MediaPipe: no {peer_python()} (`make peer`)'
    if job.needs == 'lspet' and not (Path(ctx.lspet) / 'joints.mat').exists():
        return f'no LSPET at {ctx.lspet}'
    if job.needs == 'real' and not Path(REAL).is_dir():
        return f'no real recordings at {REAL}'
    for motion, path, what in (('utkinect', ctx.utkinect, 'UTKinect'),
                               ('msraction3d', ctx.msraction3d, 'MSR Action3D')):
        if any(SETS[s].motion == motion for s in job.sets) and not Path(path).is_dir():
            return f'no {what} motion at {path} to render its sets'
    return ''


def summarize_validation() -> dict:
    """The validation sweeps' figures and the value each chooses."""
    out: dict = {'set_margin': 'valid30'}
    margin = {}
    for m in MARGINS:
        rows = json.loads((results_jobs.WORK / f'margin_{m}.json').read_text())['rows']
        r = rows['rgbd_kf_ik']
        margin[str(m)] = {'average7': r['pck']['average7'],
                          'within_10cm': r.get('within_10cm', {}).get('average'),
                          'rgbd_t_average7': rows['rgbd_t']['pck']['average7'],
                          'cpu_ms': r.get('cpu_ms', {}).get('p50'),
                          'search_cells': r.get('search_cells', {}).get('mean')}
    out['margin'] = margin
    out['margin_chosen'] = float(choose_label(
        {k: v['average7'] for k, v in margin.items()}, str(DEFAULT_MARGIN),
        {k: v['cpu_ms'] for k, v in margin.items()},
        {k: v['search_cells'] for k, v in margin.items()}))
    out['people'] = summarize_people()
    out['sweeps'] = {}
    for sweep, values in SWEEPS.items():
        table = {}
        for label, items in values.items():
            files = [sweep_file(sweep, label, d) for d in sweep_sets(sweep)]
            if not all(f.exists() for f in files):
                continue
            runs = [json.loads(f.read_text()) for f in files]
            rows = [run['rows']['rgbd_kf_ik'] for run in runs]
            frames = [run['frames'] for run in runs]
            table[label] = {
                'config': list(items), 'average7': _pooled(
                    [r['pck']['average7'] for r in rows], frames),
                'within_10cm': _pooled([r.get('within_10cm', {}).get('average')
                                        for r in rows], frames),
                'cpu_ms': _pooled([r.get('cpu_ms', {}).get('p50') for r in rows], frames),
                'search_cells': _pooled([r.get('search_cells', {}).get('mean') for r in rows],
                                        frames),
                'groups': {g: _pooled([r['pck'].get(g) for r in rows], frames)
                           for g in GROUPS7},
                'sets': {d: {'average7': r['pck']['average7'],
                             'within_10cm': r.get('within_10cm', {}).get('average'),
                             **({'tracking': {k: r['tracking'].get(k) for k in TRACKING_KEYS}}
                                if 'tracking' in r else {})}
                         for d, r in zip(sweep_sets(sweep), rows, strict=True)}}
        shipped = next(iter(values))
        # a value tracking several people worse than the shipped one is not chosen at all
        kept = {k: v for k, v in table.items()
                if shipped not in table or not tracks_worse(v, table[shipped])}
        out['sweeps'][sweep] = {'set': ' + '.join(sweep_sets(sweep)), 'shipped': shipped,
                                'values': table,
                                'tracks_worse': sorted(set(table) - set(kept)),
                                'chosen': choose_label(
                                    {k: v['average7'] for k, v in kept.items()}, shipped,
                                    {k: v['cpu_ms'] for k, v in table.items()},
                                    {k: v['search_cells'] for k, v in table.items()})}
    if (results_jobs.WORK / 'valid30_msr.json').exists():
        rows = json.loads((results_jobs.WORK / 'valid30_msr.json').read_text())
        r = rows['rows']['rgbd_kf_ik']
        out['valid30_msr'] = {'frames': rows['frames'], 'average7': r['pck']['average7'],
                              'within_10cm': r.get('within_10cm', {}).get('average'),
                              'groups': {g: r['pck'].get(g) for g in GROUPS7}}
    out['tie'] = TIE
    out['max_cpu_increase'] = MAX_CPU_INCREASE
    out['min_search_saving'] = MIN_SEARCH_SAVING
    out['max_false_increase'] = MAX_FALSE_INCREASE
    out['idf1_tie'] = IDF1_TIE
    return out


GROUPS7 = ('head', 'shoulder', 'elbow', 'wrist', 'hip', 'knee', 'ankle')
# a sweep on several-person sets: each set's tracking figures beside its average7
TRACKING_KEYS = ('mota', 'idf1', 'id_switches_per_1000', 'false_per_1000')


# a value's several-person tracking is worse than the shipped one's (`tracks_worse`) when on any
# set it has more than this many more false skeletons per 1000 frames (the bound is 1)
# or an IDF1 lower by more than IDF1_TIE
MAX_FALSE_INCREASE = 1.0
IDF1_TIE = 0.005


def tracks_worse(value: dict, shipped: dict) -> bool:
    """Whether a sweep value (`summarize_validation`'s table entry) tracks the people of any
    several-person set worse than the shipped value: more false skeletons or a lower IDF1,
    which the pooled average7 can hide (a false skeleton matched to nobody costs it nothing)."""
    for name, run in value['sets'].items():
        mine, base = run.get('tracking'), shipped['sets'].get(name, {}).get('tracking')
        if not mine or not base:
            continue
        if (mine['false_per_1000'] > base['false_per_1000'] + MAX_FALSE_INCREASE
                or mine['idf1'] < base['idf1'] - IDF1_TIE):
            return True
    return False


def _pooled(values: list[float | None], frames: list[int]) -> float | None:
    """The sets' figures weighted by their frames (None if any is missing)."""
    if any(v is None for v in values):
        return None
    return sum(v * n for v, n in zip(values, frames, strict=True)) / sum(frames)


def choose_label(scores: dict[str, float], shipped: str,
                 cpu_ms: dict[str, float | None] | None = None,
                 search_cells: dict[str, float | None] | None = None) -> str:
    """The best-scoring value's label, unless the shipped one is within `TIE` of it, or the
    best costs more than `MAX_CPU_INCREASE` more than the shipped one per frame, in CPU time
    (p50) or in the search's work (`search_cells`, the mean filter positions scored a frame:
    the same on any machine and under any load, where a p50 moves by a few % between runs
    of identical output); then the best of those that do not.

    When no value is better beyond the tie: the value that searches least among those scoring
    at least the shipped one's and searching at least `MIN_SEARCH_SAVING` less (the headroom
    on a slow robot computer), else the shipped one. That saving is judged by the count alone:
    a value doing the same search work or less cannot cost the search more CPU, and the CPU
    p50 of two values of the same output differs by up to 12 % between runs."""
    if shipped not in scores:
        return shipped

    def within(cost: dict[str, float | None] | None, k: str) -> bool:
        base = (cost or {}).get(shipped)
        value = (cost or {}).get(k)
        return base is None or value is None or value <= base * (1.0 + MAX_CPU_INCREASE)

    affordable = {k: v for k, v in scores.items()
                  if within(cpu_ms, k) and within(search_cells, k)}
    best = max(affordable, key=affordable.get)
    if scores[best] > scores[shipped] + TIE:
        return best
    cells = search_cells or {}
    base = cells.get(shipped)
    cheaper = {k: c for k, c in cells.items()
               if k in scores and scores[k] >= scores[shipped] and base is not None
               and c is not None and c <= base * (1.0 - MIN_SEARCH_SAVING)}
    return min(cheaper, key=lambda k: (cheaper[k], -scores[k])) if cheaper else shipped


def summarize_people() -> dict:
    """The several-person sweep (`tools/people_sweep.py`) over `PEOPLE_SWEEP_SETS`: each
    setting's mean MOTA over the sets and its figures on the two-person set, best first; the
    shipped setting marked."""
    files = [results_jobs.RESULTS / f'people_sweep_{s}.json' for s in PEOPLE_SWEEP_SETS]
    if not all(f.exists() for f in files):
        return {}
    runs = [json.loads(f.read_text()) for f in files]
    tracking = TrackingConfig()
    shipped = {'second_look': ForegroundConfig().second_look,
               **{k: getattr(tracking, k) for k in ('birth_score', 'confirm_frames',
                                                    'trust_score')}}
    table = []
    for rows in zip(*runs, strict=True):
        two = rows[0]
        table.append({**{k: two[k] for k in shipped},
                      'mean_mota': sum(r['mota'] for r in rows) / len(rows),
                      'average7': two['average7'], 'idf1': two['idf1'], 'mota': two['mota'],
                      'false_per_1000': two['false_per_1000'],
                      'alone_false_per_1000': [r['false_per_1000'] for r in rows[1:]],
                      'shipped': all(two[k] == v for k, v in shipped.items())})
    table.sort(key=lambda r: -r['mean_mota'])
    return {'sets': list(PEOPLE_SWEEP_SETS), 'settings': table, 'tie': TIE}


def shipped_colour_net() -> str | None:
    """The label of `COLOUR_NET_GRID` that the colour unary's defaults are (None: none is)."""
    from pose4d_ros.core.dpm.net_unary import UnaryConfig

    default = UnaryConfig()
    items = (f'unary.weight={default.weight:g}', f'unary.hog_weight={default.hog_weight:g}')
    return next((k for k, v in COLOUR_NET_GRID.items() if v == items), None)


def summarize_colour_net() -> dict:
    """Each weighting's figures on the validation sets (the renders also pooled, frames
    weighted), and the one chosen: the best PCK@0.2 average of the nodes' model on photographs
    (colour alone) among those losing at most `COLOUR_NET_RGBD_LOSS` of each render set's
    rgbd_kf_ik average7 against the colour HOG alone and tracking no several-person set worse
    than the shipped weighting (`tracks_worse`: the weight scales the pose score the tracker's
    thresholds read)."""
    table = {}
    for label, items in COLOUR_NET_GRID.items():
        files = [colour_net_file(label, d) for d in ('lspet', *COLOUR_NET_RENDERS)]
        if not all(f.exists() for f in files):
            continue
        photos, *renders = (json.loads(f.read_text()) for f in files)
        (photo,) = photos['rows'].values()
        rows = [run['rows']['rgbd_kf_ik'] for run in renders]
        frames = [run['frames'] for run in renders]
        table[label] = {
            'config': list(items),
            'lspet': {'pck': photo['pck']['average'], 'pck@0.2': photo['pck@0.2']['average'],
                      'cpu_ms': photo.get('cpu_ms', {}).get('p50')},
            'renders': {'average7': _pooled([r['pck']['average7'] for r in rows], frames),
                        'within_10cm': _pooled([r.get('within_10cm', {}).get('average')
                                                for r in rows], frames),
                        'cpu_ms': _pooled([r.get('cpu_ms', {}).get('p50') for r in rows],
                                          frames)},
            'sets': {s: {'average7': r['pck']['average7'],
                         'within_10cm': r.get('within_10cm', {}).get('average'),
                         **({'tracking': {k: r['tracking'][k] for k in TRACKING_KEYS}}
                            if r.get('tracking') else {})}
                     for s, r in zip(COLOUR_NET_RENDERS, rows, strict=True)}}
    out: dict = {'network': COLOUR_NET, 'photographs': f'LSPET {COLOUR_NET_VALID}',
                 'renders': ' + '.join(COLOUR_NET_RENDERS),
                 'max_rgbd_loss': COLOUR_NET_RGBD_LOSS, 'values': table}
    if 'none' in table:
        base = table['none']['sets']
        shipped = table.get(shipped_colour_net())
        ok = {k: v for k, v in table.items()
              if all(v['sets'][s]['average7'] >= base[s]['average7'] - COLOUR_NET_RGBD_LOSS
                     for s in COLOUR_NET_RENDERS)
              and not (shipped and tracks_worse(v, shipped))}
        out['chosen'] = max(ok, key=lambda k: ok[k]['lspet']['pck@0.2'])
        out['best_on_photographs'] = max(table, key=lambda k: table[k]['lspet']['pck@0.2'])
    return out
