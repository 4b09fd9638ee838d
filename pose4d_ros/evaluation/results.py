"""Every figure the READMEs report, from one command (`pose4d results`, `make results`).

The protocol (`pose4d_ros/models/README.md`, first section): training, validation and test sets
are disjoint by subject and seed; settings are chosen on validation sets; the test sets are run
once per shipped model, to report. This module holds that protocol's sets (`SETS`: each a
`pose4d synth` command, made into `data/synth/NAME` unless a set made by the same command is
there) and its jobs (`JOBS`: `pose4d eval` and `pose4d bench` commands, each writing JSON under
`docs/results/`), runs them as the user would type them (subprocesses of the `pose4d` beside
this Python, their progress lines passed through), and writes `docs/results/index.json` (per
job: the commands, when, how long, done or skipped and why; the machine; the commit) and the
generated `docs/RESULTS.md` and README summary (`evaluation.results_doc`).
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pose4d_ros.core.files import write_json
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.people import TrackingConfig
from pose4d_ros.peer import peer_python
from pose4d_ros.util.machine import git_commit, machine
from pose4d_ros.util.progress import log

RESULTS = Path('docs/results')
DATA = Path('data/synth')
WORK = Path('build/results')
STAMP = '.pose4d_command'


# the shared data's default places (the Makefile's, from the repository root)
UTKINECT = '../shared/data/utkinect'
MSRACTION3D = '../shared/data/msraction3d'
LSPET = '../shared/data/lspet'
REAL = '../shared/data/real'
# Real development recordings (no joint labels: MediaPipe the reference, our hand labels for
# people and ghosts): never test data, they are looked at after every change. Folder: options.
# Separate frames are held 20 frames each (a still camera's stream, as a tracker sees it).
REAL_SETS = {'lab_walk': ('--fps', '10'), 'outdoor4': ('--hold', '20'),
             'kinect2_masked': ('--hold', '20')}
# each as the nodes run by default, and with the photograph network in the colour unary
REAL_VARIANTS = {'': (), '_net': ('--colour-net', 'lspet_convnet')}


@dataclass(frozen=True)
class DataSet:
    """A rendered set: its role in the protocol, the real motion it is posed by ('utkinect' or
    'msraction3d') and its `pose4d synth` options (after `--<motion> DIR --out DIR`)."""

    name: str
    role: str  # 'training', 'validation' or 'test'
    options: tuple[str, ...]
    motion: str = 'utkinect'
    bag: bool = False  # also written as a bag, `<name>_bag` beside it (`pose4d cad60-to-bag`)

    def command(self, utkinect: str = UTKINECT, msraction3d: str = MSRACTION3D) -> list[str]:
        source = msraction3d if self.motion == 'msraction3d' else utkinect
        return ['pose4d', 'synth', f'--{self.motion}', source, '--out', str(DATA / self.name),
                *self.options, '--quiet']


def _synth(seed: int, takes: str, per_take: int, frames: int, stride: int,
           *more: str) -> tuple[str, ...]:
    return ('--seed', str(seed), '--takes', takes, '--videos-per-take', str(per_take),
            '--frames', str(frames), '--stride', str(stride), *more)


ARMS = ('--actions', 'waveHands,clapHands,throw', '--stature', '1.7', '2.0',
        '--distance', '1.8', '3.2')
# MSR Action3D motion none of our sets was shaped on (the kinds: punches, throws, bends,
# kicks, jogging, tennis and golf swings; fixed before any was measured): each sequence is one
# action of 2-3.4 s, cut into two 30-frame windows (its start and its end)
MSR_ACTIONS = ('--actions', 'forwardPunch,highThrow,bend,forwardKick,sideKick,jogging,'
               'tennisSwing,tennisServe,golfSwing,pickUpThrow')
SETS: dict[str, DataSet] = {s.name: s for s in (
    # training renders (subjects s01-s06): the peer's depth offsets are fitted here
    DataSet('train', 'training', _synth(1, 's01-s06', 8, 16, 3)),
    # validation: the training subjects, new bodies and rooms (seeds no model was trained on)
    DataSet('valid30', 'validation', _synth(97, 's01-s06', 1, 45, 1)),
    DataSet('valid30_people2', 'validation', _synth(98, 's01-s06', 1, 45, 1, '--people', '2')),
    DataSet('valid60_people2', 'validation', _synth(201, 's01-s06', 1, 60, 1, '--people', '2')),
    DataSet('valid60_people3', 'validation', _synth(203, 's01-s06', 1, 60, 1, '--people', '3')),
    DataSet('valid30_people2b', 'validation', _synth(99, 's01-s06', 2, 45, 1, '--people', '2')),
    DataSet('valid60_people3b', 'validation', _synth(205, 's01-s06', 2, 60, 1, '--people', '3')),
    DataSet('valid60_people3c', 'validation', _synth(207, 's01-s06', 3, 60, 1, '--people', '3')),
    DataSet('valid60_people3d', 'validation', _synth(209, 's01-s06', 3, 60, 1, '--people', '3')),
    *(DataSet(f'valid60_people2_alone{k}', 'validation',
              _synth(201, 's01-s06', 1, 60, 1, '--people', '2', '--alone', str(k)))
      for k in (1, 2)),
    # people near the camera (1.2-2 m), cut by the image's bottom edge: the cut height's set
    DataSet('valid30_near', 'validation',
            _synth(403, 's01-s06', 2, 30, 1, '--distance', '1.2', '2.0')),
    # MSR Action3D motion of the training subjects (take 1 of each action)
    DataSet('valid30_msr', 'validation',
            _synth(402, ','.join(f's0{k}_e01' for k in range(1, 7)), 1, 30, 1, *MSR_ACTIONS),
            motion='msraction3d'),
    # test: the held-out subjects s07-s08, run once per shipped model
    DataSet('test', 'test', _synth(2, 's07-s08', 5, 20, 3)),
    DataSet('test30', 'test', _synth(3, 's07-s08', 4, 45, 1)),
    DataSet('test30_arms', 'test', _synth(96, 's07-s08', 2, 45, 1, *ARMS)),
    DataSet('test30_people2', 'test', _synth(4, 's07-s08', 2, 45, 1, '--people', '2')),
    # two people, and the same videos with each of them alone (the baseline); three people
    DataSet('test60_people2', 'test', _synth(101, 's07-s08', 3, 60, 1, '--people', '2')),
    DataSet('test60_people2_alone1', 'test',
            _synth(101, 's07-s08', 3, 60, 1, '--people', '2', '--alone', '1')),
    DataSet('test60_people2_alone2', 'test',
            _synth(101, 's07-s08', 3, 60, 1, '--people', '2', '--alone', '2')),
    DataSet('test60_people3', 'test', _synth(301, 's07-s08', 2, 60, 1, '--people', '3')),
    # a second held-out three-person set (another seed, twice the videos), made after the
    # first's false skeletons were not found on any three-person validation set
    DataSet('test60_people3b', 'test', _synth(303, 's07-s08', 4, 60, 1, '--people', '3')),
    # the headroom issue's bench bag: four held-out videos of 75 frames at 30 fps, replayed at
    # 1x through both graphs while the ros2 command line queries the nodes
    DataSet('bench300', 'test', _synth(300, 's07-s08', 1, 75, 1), bag=True),
    # MSR Action3D motion of the held-out subjects (takes 1 and 2 of each action)
    DataSet('test30_msr', 'test',
            _synth(401, 's07_e01,s07_e02,s08_e01,s08_e02', 2, 30, 1, *MSR_ACTIONS),
            motion='msraction3d'),
)}

# Validation sweeps: the values tried (the shipped default among them); another value is chosen
# only when it beats the default by more than TIE points of average7 (`choose_label`)
MARGINS = (0.3, 0.4, 0.5, 0.6)
DEFAULT_MARGIN = 0.4
TIE = 0.1
# a value costing more CPU per frame (p50) than this fraction over the shipped one's is not
# chosen for accuracy alone (the headroom on a slow robot computer comes first)
MAX_CPU_INCREASE = 0.05
# a value at least as accurate as the shipped one that searches at least this fraction less (in
# filter positions scored a frame) is chosen when no value is better beyond TIE
MIN_SEARCH_SAVING = 0.05
# the several-person sweep's sets (tools/people_sweep.py)
PEOPLE_SWEEP_SETS = ('valid60_people2', 'valid60_people2_alone1', 'valid60_people2_alone2')
_ARMS = 'left_elbow,left_wrist,right_elbow,right_wrist'
_LIMBS = _ARMS + ',left_knee,left_ankle,right_knee,right_ankle'
# settings once chosen on test sets, swept on validation by `pose4d eval --config` (each
# value's settings; the first is the shipped one, whose run on valid30 is the margin sweep's
# DEFAULT_MARGIN run); on valid30 but where SWEEP_SETS says (valid30 has nobody cut by the
# image's edge, so every cut height gives the same frames there); with several sets, the choice
# is on their frames pooled (each set's average7 weighted by its frames)
SWEEPS: dict[str, dict[str, tuple[str, ...]]] = {
    # ForegroundConfig.person_min_cut_height_m
    'cut_height': {'0.4': (), **{str(h): (f'foreground.person_min_cut_height_m={h}',)
                                 for h in (0.3, 0.5, 0.6)}},
    # the limb rule's form (SlqeConfig.limb_parts, limb_rejected_frames; 'off': no limb rule)
    'limb_rule': {'arms_second': (), 'arms_first': ('slqe.limb_rejected_frames=0',),
                  'limbs_second': (f'slqe.limb_parts={_LIMBS}',),
                  'limbs_first': (f'slqe.limb_parts={_LIMBS}', 'slqe.limb_rejected_frames=0'),
                  'off': ('slqe.limb_tolerance=0',)},
    # the person scale's factors and warm-up (ScaleConfig: 0.87-1.15 with a 2-frame warm-up
    # and no probe shipped, chosen on validation over 0.87-1.32, first shipped, the 4-frame
    # warm-up and the probe of a neighbouring scale every 8th frame, shipped before; '1': the
    # depth's scale alone)
    'person_scale': {'0.87-1.15': (), '4_frames': ('scale.warm_up_frames=4',),
                     '8_frames': ('scale.warm_up_frames=8',),
                     '0.87-1.32': ('scale.factors=0.87,1,1.15,1.32',),
                     '0.76-1.52': ('scale.factors=0.76,0.87,1,1.15,1.32,1.52',),
                     '1': ('scale.factors=1',),
                     # a neighbouring scale probed every 8th or 16th frame after the warm-up
                     'probe_8': ('scale.probe_every=8',), 'probe_16': ('scale.probe_every=16',)},
    # ForegroundConfig.floor_max_below (0: no rule, the floor before)
    'floor_below': {'0.25': (), **{str(b): (f'foreground.floor_max_below={b}',)
                                   for b in (0, 0.1, 0.5)}},
    # the several-person association's rules (TrackingConfig.confirmed_first, held_continues)
    'tracking_rules': {'both': (), 'one_assignment': ('tracking.confirmed_first=false',),
                       'held_by_birth_score': ('tracking.held_continues=false',),
                       'neither': ('tracking.confirmed_first=false',
                                   'tracking.held_continues=false')},
    # a person of the previous frame bending (ForegroundConfig.person_min_bent_top_m; 'off':
    # the usual rules for everyone, the foreground before): chosen on validation
    'bent_top': {'0.5': (), **{str(t): (f'foreground.person_min_bent_top_m={t}',)
                               for t in (0.4, 0.7)},
                 'off': ('foreground.person_min_bent_top_m=inf',)},
    # how long a person held behind a nearer one keeps their track unseen
    # (TrackingConfig.max_hidden_s; '1': max_unseen_s, the tracker before)
    'hidden': {'2': (), **{str(s): (f'tracking.max_hidden_s={s}',) for s in (1, 3)}},
    # the foreground's component tree on every 2nd (shipped), 3rd or 4th pixel
    # (ForegroundConfig.tree_step): at 3 and 4 the foreground's CPU 10 % and 24 % less (the
    # demo bag, one core: 3.4 -> 3.0 and 2.6 ms a frame)
    'tree_step': {'2': (), **{str(s): (f'foreground.tree_step={s}',) for s in (3, 4)}},
    # the floor of a part's response where a nearer person hides the searched one
    # (SearchConfig.occluded_quantile; '0': off, the detector before)
    'occluded': {'0.5': (), **{str(q): (f'search.occluded_quantile={q}',)
                               for q in (0, 0.3, 0.7)}},
    # the least score of a detection coming out from behind a nearer person that starts or
    # grows a tentative track (TrackingConfig.emerging_score; '5': birth_score, the tracker
    # before)
    'emerging': {'3': (), **{str(v): (f'tracking.emerging_score={v}',) for v in (5, 4, 2)}},
    # from behind whom a held track takes a detection (TrackingConfig.held_own_front; 'any':
    # from behind any nearer person, the tracker before)
    'held_front': {'own': (), 'any': ('tracking.held_own_front=false',)},
}


# the several-person held-out sets (the `people` job)
PEOPLE_TESTS = ('test60_people2', 'test60_people2_alone1', 'test60_people2_alone2',
                'test60_people3', 'test60_people3b')
# the several-person validation sets (two and three people, 3960 frames)
PEOPLE_SETS = ('valid60_people2', 'valid60_people3', 'valid30_people2b', 'valid60_people3b')
SWEEP_SETS = {'cut_height': ('valid30_near',),
              'person_scale': ('valid30', 'valid30_msr', 'valid60_people2'),
              'floor_below': ('valid30', 'valid30_msr', 'valid30_near'),
              'tracking_rules': ('valid60_people2', 'valid60_people3', 'valid30_people2b'),
              'bent_top': ('valid30_msr', 'valid60_people2'),
              'hidden': ('valid60_people2', 'valid60_people3', 'valid30_people2b'),
              'tree_step': ('valid30', 'valid30_msr', 'valid60_people2'),
              'occluded': PEOPLE_SETS, 'emerging': PEOPLE_SETS,
              'held_front': (*PEOPLE_SETS, 'valid60_people3c', 'valid60_people3d')}
# the shipped settings' run on a set, made anyway (the margin sweep's, valid30_msr's own)
SHIPPED_RUNS = {'valid30': f'margin_{DEFAULT_MARGIN}.json', 'valid30_msr': 'valid30_msr.json'}


def sweep_sets(sweep: str) -> tuple[str, ...]:
    return SWEEP_SETS.get(sweep, ('valid30',))


def sweep_file(sweep: str, label: str, data: str) -> Path:
    """The table of one value of a validation sweep on set `data` (the shipped value's: the
    run of the shipped settings on that set, when there is one)."""
    if label == next(iter(SWEEPS[sweep])) and data in SHIPPED_RUNS:
        return WORK / SHIPPED_RUNS[data]
    return WORK / f'{sweep}_{label}_{data}.json'


@dataclass
class Context:
    utkinect: str
    lspet: str
    peer: bool
    dry: bool = False
    commands: list[str] = field(default_factory=list)
    msraction3d: str = MSRACTION3D

    def set_command(self, name: str) -> list[str]:
        """The `pose4d synth` command of set `name`, from this context's shared data."""
        return SETS[name].command(self.utkinect, self.msraction3d)


def _eval(ctx: Context, source: str, out: Path, *options: str, peer: bool = True) -> list[str]:
    cmd = ['pose4d', 'eval', source, '--json', str(out), *options]
    if peer and ctx.peer:
        cmd += ['--peer', 'mediapipe']
        if (RESULTS / 'peer_depth.json').exists() or ctx.dry:
            cmd += ['--peer-depth', str(RESULTS / 'peer_depth.json')]
    return cmd


@dataclass(frozen=True)
class Job:
    """One table's worth of work: the sets it needs and its commands (given the context)."""

    name: str
    what: str
    sets: tuple[str, ...]
    commands: Callable[[Context], list[list[str]]]
    needs_peer: bool = False
    needs: str = ''  # 'lspet': shared data it reads besides its sets' motion
    # its commands are independent evaluations that may run side by side (`run(parallel=N)`):
    # only for jobs whose figures are accuracies and search work, never timings
    parallel: bool = False


def _validation(ctx: Context) -> list[list[str]]:
    cmds = [_eval(ctx, str(DATA / 'valid30'), WORK / f'margin_{m}.json', '--model', 'rgbd_14',
                  '--margin', str(m), '--no-single-frame', peer=False) for m in MARGINS]
    # MSR Action3D motion of the training subjects, the shipped settings (for future choices)
    cmds.append(_eval(ctx, str(DATA / 'valid30_msr'), WORK / 'valid30_msr.json', '--model',
                      'rgbd_14', '--no-single-frame', peer=False))
    cmds += [_eval(ctx, str(DATA / data), sweep_file(sweep, label, data), '--model',
                   'rgbd_14', *(a for item in items for a in ('--config', item)),
                   '--no-single-frame', peer=False)
             for sweep, values in SWEEPS.items() for label, items in values.items()
             for data in sweep_sets(sweep)
             if sweep_file(sweep, label, data).name not in SHIPPED_RUNS.values()]
    # the several-person tracker's birth score, confirmation and trust score (TrackingConfig)
    # and the foreground's second look, on two people and on each of them alone, the
    # detections computed once per foreground setting (tools/people_sweep.py)
    cmds += [[sys.executable, 'tools/people_sweep.py', str(DATA / s), '--birth-score',
              '3,4,5,6', '--confirm-frames', '2,3', '--trust-score', '5,7,9,inf',
              '--second-look', 'false,true', '--json',
              str(RESULTS / f'people_sweep_{s}.json')]
             for s in PEOPLE_SWEEP_SETS]
    return cmds


# The photograph network as the detector's colour unary (core.dpm.net_unary, the detector
# node's detector.colour_net): its weights swept on validation (LSPET 8501-9000, which no
# network saw, the nodes' rgbd_14 by its colour channel alone; valid30 and valid30_msr, RGB-D
# as the nodes run it), the first value the colour HOG alone (no network)
COLOUR_NET = 'lspet_convnet'
COLOUR_NET_VALID = '8501-9000'
COLOUR_NET_RENDERS = ('valid30', 'valid30_msr')
COLOUR_NET_GRID: dict[str, tuple[str, ...]] = {
    'none': (), **{f'w{w:g}_h{h:g}': (f'unary.weight={w:g}', f'unary.hog_weight={h:g}')
                   for w, h in ((1, 1), (2, 1), (4, 1), (16, 1), (4, 0), (16, 0))}}
# the RGB-D rows may lose at most this much of each render set's rgbd_kf_ik average7 against
# none (the issue: every RGB-D table within 0.5)
COLOUR_NET_RGBD_LOSS = 0.5


def colour_net_file(label: str, data: str) -> Path:
    return WORK / f'colour_net_{label}_{data}.json'


def _colour_net(ctx: Context) -> list[list[str]]:
    cmds = []
    for label, items in COLOUR_NET_GRID.items():
        net = ('--colour-net', COLOUR_NET) if items else ()
        config = [a for item in items for a in ('--config', item)]
        cmds.append(_eval(ctx, ctx.lspet, colour_net_file(label, 'lspet'), '--range',
                          COLOUR_NET_VALID, '--model', 'rgbd_14', *net, *config, peer=False))
        cmds += [_eval(ctx, str(DATA / s), colour_net_file(label, s), '--model', 'rgbd_14',
                       *net, *config, '--no-single-frame', peer=False)
                 for s in COLOUR_NET_RENDERS]
    return cmds


def _lspet(ctx: Context) -> list[list[str]]:
    cmds = [_eval(ctx, ctx.lspet, RESULTS / 'lspet.json', '--range', '2501-3000', '--model',
                  'lspet_convnet', '--model', 'lspet_rgb_14', '--model', 'rgbd_14')]
    chosen = chosen_colour_net()
    if chosen:
        cmds.append(_eval(ctx, ctx.lspet, RESULTS / 'lspet_colour_net.json', '--range',
                          '2501-3000', '--model', 'rgbd_14', '--colour-net', COLOUR_NET,
                          *(a for item in chosen for a in ('--config', item)), peer=False))
    return cmds


# the held-out RGB-D sets the chosen colour network is reported on (not the nodes' default)
COLOUR_NET_TESTS = ('test', 'test30', 'test30_msr')


def _colour_net_test(ctx: Context) -> list[list[str]]:
    """Each held-out set with the network at the chosen weights, and without it in the same
    run (the nodes' default, so that the two rows come from one machine and one render)."""
    chosen = chosen_colour_net()
    if not chosen:
        return []
    cmds = []
    for s in COLOUR_NET_TESTS:
        cmds.append(_eval(ctx, str(DATA / s), RESULTS / f'colour_net_{s}_none.json', '--model',
                          'rgbd_14', '--no-single-frame', peer=False))
        cmds.append(_eval(ctx, str(DATA / s), RESULTS / f'colour_net_{s}.json', '--model',
                          'rgbd_14', '--colour-net', COLOUR_NET,
                          *(a for item in chosen for a in ('--config', item)),
                          '--no-single-frame', peer=False))
    return cmds


def chosen_colour_net() -> tuple[str, ...]:
    """The colour network's weighting chosen on validation (`docs/results/colour_net.json`),
    as `--config` items; () when none is chosen or it is the colour HOG alone."""
    path = RESULTS / 'colour_net.json'
    if not path.exists():
        return ()
    chosen = json.loads(path.read_text()).get('chosen')
    return COLOUR_NET_GRID.get(chosen, ()) if chosen else ()


def summarize_colour_net() -> dict:
    """Each weighting's figures on the validation sets (the renders also pooled, frames
    weighted), and the one chosen: the best PCK@0.2 average of the nodes' model on photographs
    (colour alone) among those losing at most `COLOUR_NET_RGBD_LOSS` of each render set's
    rgbd_kf_ik average7 against the colour HOG alone."""
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
                         'within_10cm': r.get('within_10cm', {}).get('average')}
                     for s, r in zip(COLOUR_NET_RENDERS, rows, strict=True)}}
    out: dict = {'network': COLOUR_NET, 'photographs': f'LSPET {COLOUR_NET_VALID}',
                 'renders': ' + '.join(COLOUR_NET_RENDERS),
                 'max_rgbd_loss': COLOUR_NET_RGBD_LOSS, 'values': table}
    if 'none' in table:
        base = table['none']['sets']
        ok = {k: v for k, v in table.items()
              if all(v['sets'][s]['average7'] >= base[s]['average7'] - COLOUR_NET_RGBD_LOSS
                     for s in COLOUR_NET_RENDERS)}
        out['chosen'] = max(ok, key=lambda k: ok[k]['lspet']['pck@0.2'])
        out['best_on_photographs'] = max(table, key=lambda k: table[k]['lspet']['pck@0.2'])
    return out


JOBS: tuple[Job, ...] = (
    Job('peer_depth', "MediaPipe's per-joint depth offsets, fitted on the training renders",
        ('train',), lambda c: [[
            'pose4d', 'eval', str(DATA / 'train'), '--json', str(WORK / 'peer_depth_train.json'),
            '--peer', 'mediapipe', '--fit-peer-depth', str(RESULTS / 'peer_depth.json')]],
        needs_peer=True),
    Job('validation', 'the search margin, the cut height, the limb rule, the person scale, the '
        "floor, the several-person tracker and its association's rules, swept on validation "
        'renders; the MSR Action3D validation set',
        ('valid30', 'valid30_near', 'valid60_people2', 'valid60_people2_alone1',
         'valid60_people2_alone2', 'valid60_people3', 'valid30_people2b', 'valid60_people3b',
         'valid60_people3c', 'valid60_people3d',
         'valid30_msr'),
        _validation, parallel=True),
    Job('colour_net', "the photograph network as the detector's colour unary, its weights "
        'swept on validation: LSPET 8501-9000 (colour alone), valid30 and valid30_msr (RGB-D)',
        COLOUR_NET_RENDERS, _colour_net, needs='lspet', parallel=True),
    Job('test', 'held-out test (s07-s08, 400 frames 0.1 s apart): rgbd_14 and rgb_10',
        ('test',), lambda c: [_eval(c, str(DATA / 'test'), RESULTS / 'test.json')]),
    Job('test30', 'held-out test30 (720 frames at 30 fps), with the PCK curves',
        ('test30',), lambda c: [_eval(c, str(DATA / 'test30'), RESULTS / 'test30.json',
                                      '--model', 'rgbd_14', '--plot',
                                      str(RESULTS / 'pck_test30.png'))]),
    Job('test30_arms', 'held-out test30_arms (1064 frames of waving, clapping, throwing)',
        ('test30_arms',), lambda c: [_eval(c, str(DATA / 'test30_arms'),
                                           RESULTS / 'test30_arms.json', '--model', 'rgbd_14')]),
    Job('test30_msr', 'held-out MSR Action3D motion (s07-s08, 10 actions never shaped on: '
        'kicks, punches, bends, swings, throws, jogging; 30 fps)',
        ('test30_msr',), lambda c: [_eval(c, str(DATA / 'test30_msr'),
                                          RESULTS / 'test30_msr.json', '--model', 'rgbd_14')]),
    Job('sample', 'the demo bag (bags/sample, 45 frames)', (),
        lambda c: [_eval(c, 'bags/sample', RESULTS / 'sample.json', '--model', 'rgbd_14')]),
    Job('test30_people2', 'held-out two-person renders (several-person pipeline)',
        ('test30_people2',), lambda c: [_eval(c, str(DATA / 'test30_people2'),
                                              RESULTS / 'test30_people2.json', '--model',
                                              'rgbd_14', peer=False)]),
    Job('people', 'held-out renders of two and three people (60 frames a video, crossings), '
        'and the same two-person videos with each person alone, in the several-person pipeline',
        PEOPLE_TESTS,
        lambda c: [_eval(c, str(DATA / s), RESULTS / f'{s}.json', '--model', 'rgbd_14',
                         '--max-people', '4', peer=False) for s in PEOPLE_TESTS]),
    Job('lspet', 'LSPET photographs 2501-3000: the photograph network, the photograph part '
        "model, and the nodes' rgbd_14 by its colour channel alone, without and with the "
        'photograph network in its colour unary (the weights chosen on validation)', (),
        _lspet, needs='lspet'),
    Job('colour_net_test', "the held-out RGB-D sets with the photograph network in the "
        "detector's colour unary at the weights chosen on validation (not the nodes' default)",
        COLOUR_NET_TESTS, _colour_net_test),
    Job('real', 'real RGB-D recordings (development data: Xtion lab walk, Kinect v2 outdoors '
        'and masked): agreement with MediaPipe, people found and ghosts against hand labels',
        (), lambda c: [_eval(c, f'{REAL}/{name}', RESULTS / f'real_{name}{suffix}.json',
                             *options, *variant, '--labels', f'labels/real/{name}.json')
                       for name, options in REAL_SETS.items()
                       for suffix, variant in REAL_VARIANTS.items()], needs='real'),
    Job('bench', 'CPU per stage on the demo bag, and MediaPipe in the same run; again on '
        "the nodes' several-person path", (),
        lambda c: [['pose4d', 'bench', 'bags/sample', '--json', str(RESULTS / name),
                    *people, *(['--peer', 'mediapipe'] if c.peer else [])]
                   for name, people in (('bench.json', []),
                                        ('bench_people.json', ['--people', 'several']))]),
    Job('bench_people3', 'CPU per stage by the number of people tracked in a frame (1-3: the '
        "held-out three-person renders, every frame, the nodes' several-person path)",
        ('test60_people3',),
        lambda c: [['pose4d', 'bench', str(DATA / 'test60_people3'), '--json',
                    str(RESULTS / 'bench_people3.json'), '--people', 'several', '--frames',
                    '480']]),
    Job('bench_colour_net', "CPU per stage as the nodes run them with the photograph network "
        "in the detector's colour unary, and without it, in the same session, with MediaPipe",
        (), lambda c: [['pose4d', 'bench', 'bags/sample', '--json', str(RESULTS / name),
                        '--people', 'several', *net, *(['--peer', 'mediapipe'] if c.peer else [])]
                       for name, net in (('bench_colour_net_none.json', []),
                                         ('bench_colour_net.json',
                                          ['--colour-net', COLOUR_NET]))]),
    Job('bench_graph', 'the node graph on the demo bag: frames in and out, latency', (),
        lambda c: [['pose4d', 'bench', 'bags/sample', '--json',
                    str(RESULTS / 'bench_graph.json'), '--frames', '20', '--graph']]),
    Job('bench_graph300', 'both graphs replaying 300 frames at 30 fps (1x) while the ros2 command '
        'line queries the nodes (topic hz, param get): frames in and out, latency',
        ('bench300',), lambda c: [['pose4d', 'bench', str(DATA / 'bench300_bag'), '--json',
                                   str(RESULTS / 'bench_graph300.json'), '--frames', '20',
                                   '--graph', '--load', 'query']]),
    Job('bench_graph_people2', 'both graphs replaying the two-person demo bag '
        '(bags/sample_people2, 50 frames) at 30 fps (1x): frames in and out, latency', (),
        lambda c: [['pose4d', 'bench', 'bags/sample_people2', '--json',
                    str(RESULTS / 'bench_graph_people2.json'), '--frames', '20', '--graph']]),
)
JOB_NAMES = tuple(j.name for j in JOBS)


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
    out = DATA / ds.name
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
    for d in (RESULTS, WORK, DATA):
        d.mkdir(parents=True, exist_ok=True)
    index_path = RESULTS / 'index.json'
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
                write_json(RESULTS / 'validation.json', summarize_validation(), indent=1)
            if job.name == 'colour_net':
                write_json(RESULTS / 'colour_net.json', summarize_colour_net(), indent=1)
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
    results_doc.write_all(RESULTS, index)
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
        rows = json.loads((WORK / f'margin_{m}.json').read_text())['rows']
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
    if (WORK / 'valid30_msr.json').exists():
        rows = json.loads((WORK / 'valid30_msr.json').read_text())
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
    files = [RESULTS / f'people_sweep_{s}.json' for s in PEOPLE_SWEEP_SETS]
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
