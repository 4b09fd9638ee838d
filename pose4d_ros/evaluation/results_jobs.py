"""What `pose4d results` runs (`evaluation.results` runs it, and is where to import it from).

The protocol's sets (`SETS`: each a `pose4d synth` command, made into `data/synth/NAME`), its
validation sweeps (`MARGINS`, `SWEEPS` and the sets each is judged on, `SWEEP_SETS`), the
photograph network's weights swept on validation and the weighting chosen
(`COLOUR_NET_GRID`, `chosen_colour_net`) and its jobs (`JOBS`: `pose4d eval` and
`pose4d bench` commands given a `Context`, each writing JSON under `docs/results/`), with the
folders they read and write (`RESULTS`, `DATA`, `WORK`: read here and in `evaluation.results`
through this module, so that pointing them elsewhere is done here alone). Declarations: nothing
here runs a command.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

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
# lab_walk's Xtion has its depth 8 px left of and 3 px below its colour image: the shift its
# own edges give (`core.registration.edge_shift`, printed by `pose4d eval` as registration),
# as a user gives it to the nodes (foreground.depth_shift_px); the others measure 0, 0
REAL_SETS = {'lab_walk': ('--fps', '10', '--depth-shift', '8,3'), 'outdoor4': ('--hold', '20'),
             'kinect2_masked': ('--hold', '20')}
# each as the nodes run by default (the photograph network in the colour unary), and without
# the network (the part model's HOG filters alone)
REAL_VARIANTS = {'': (), '_nonet': ('--colour-net', 'none')}


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
# a camera mounted above the heads, looking down (a lab's or a hall's wall camera: the real lab
# recording's is 2.35 m high, pitched 29-30 degrees), people 2.4-4.2 m away
MOUNTED = ('--camera-height', '2.0', '2.7', '--camera-pitch', '20', '35')
MOUNTED_ONE = (*MOUNTED, '--distance', '2.4', '4.2')
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
    # seen by the mounted camera: one person, and three
    DataSet('valid30_high', 'validation', _synth(305, 's01-s06', 1, 45, 1, *MOUNTED_ONE)),
    DataSet('valid60_people3_high', 'validation',
            _synth(321, 's01-s06', 1, 60, 1, '--people', '3', *MOUNTED)),
    # a second, twice as large (made when the held-out three-person set showed legs seen from
    # above taken for people, which the first showed in 2 of its 12 videos)
    DataSet('valid60_people3b_high', 'validation',
            _synth(325, 's01-s06', 2, 60, 1, '--people', '3', *MOUNTED)),
    # and a third (made when the held-out set, after the one-body rule, still had 181 false
    # skeletons per 1000 frames and the second 2.1)
    DataSet('valid60_people3c_high', 'validation',
            _synth(327, 's01-s06', 2, 60, 1, '--people', '3', *MOUNTED)),
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
    # seen by the mounted camera (the one-person set with MediaPipe in the same run)
    DataSet('test30_high', 'test', _synth(313, 's07-s08', 4, 45, 1, *MOUNTED_ONE)),
    DataSet('test60_people3_high', 'test',
            _synth(323, 's07-s08', 2, 60, 1, '--people', '3', *MOUNTED)),
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
# the held-out sets from the mounted camera (the `mounted` job): one person, three
MOUNTED_TESTS = ('test30_high', 'test60_people3_high')


def _people(data: str) -> tuple[str, ...]:
    """The several-person pipeline's options for a set of several people."""
    return ('--max-people', '4') if '_people' in data else ()


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
# network saw, the nodes' rgbd_14 by its colour channel alone; valid30, valid30_msr and
# valid60_people3, RGB-D as the nodes run it), the first value the colour HOG alone (no
# network). The three-person set since the network was fine-tuned on renders in their rooms:
# the weight also moves the pose score whose calibration (UnaryConfig.score_offset) the
# tracker's birth thresholds read, and weight 16, chosen on the single-person sets, lost 1.6
# points of average7 there (85.90 against 87.48 at weight 4) and found 39 of outdoor4's 80
# people against 58. With rgbd_14 retrained (mounted-camera renders) the rule chose weight 16
# again (valid60_people3 -0.27 against weight 4), which made 6.9 false skeletons per 1000
# frames on valid60_people2 (0 at weight 4) and found 109 of lab_walk's 228 labelled people
# against 149: the two-person set is among the renders now, and a weighting that tracks any
# several-person set worse than the shipped one (`results.tracks_worse`, the guard of every
# validation sweep) is not chosen
COLOUR_NET = 'lspet_convnet'
COLOUR_NET_VALID = '8501-9000'
COLOUR_NET_RENDERS = ('valid30', 'valid30_msr', 'valid60_people2', 'valid60_people3')
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
        net = ('--colour-net', COLOUR_NET if items else 'none')
        config = [a for item in items for a in ('--config', item)]
        cmds.append(_eval(ctx, ctx.lspet, colour_net_file(label, 'lspet'), '--range',
                          COLOUR_NET_VALID, '--model', 'rgbd_14', *net, *config, peer=False))
        cmds += [_eval(ctx, str(DATA / s), colour_net_file(label, s), '--model', 'rgbd_14',
                       *net, *config, '--no-single-frame', peer=False)
                 for s in COLOUR_NET_RENDERS]
    return cmds


def _lspet(ctx: Context) -> list[list[str]]:
    cmds = [_eval(ctx, ctx.lspet, RESULTS / 'lspet.json', '--range', '2501-3000', '--model',
                  'lspet_convnet', '--model', 'lspet_rgb_14', '--model', 'rgbd_14',
                  '--colour-net', 'none')]
    chosen = chosen_colour_net()
    if chosen:
        cmds.append(_eval(ctx, ctx.lspet, RESULTS / 'lspet_colour_net.json', '--range',
                          '2501-3000', '--model', 'rgbd_14', '--colour-net', COLOUR_NET,
                          *(a for item in chosen for a in ('--config', item)), peer=False))
    return cmds


# the held-out RGB-D sets the chosen colour network is reported on beside the part model alone
COLOUR_NET_TESTS = ('test', 'test30', 'test30_msr')


def _colour_net_test(ctx: Context) -> list[list[str]]:
    """Each held-out set with the network at the chosen weights (the nodes' default), and
    without it in the same run (so that the two rows come from one machine and one render)."""
    chosen = chosen_colour_net()
    if not chosen:
        return []
    cmds = []
    for s in COLOUR_NET_TESTS:
        cmds.append(_eval(ctx, str(DATA / s), RESULTS / f'colour_net_{s}_none.json', '--model',
                          'rgbd_14', '--colour-net', 'none', '--no-single-frame', peer=False))
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
        'swept on validation: LSPET 8501-9000 (colour alone), valid30, valid30_msr, '
        'valid60_people2 and valid60_people3 (RGB-D)',
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
    Job('mounted', 'held-out renders from a camera mounted above the heads (2.0-2.7 m, '
        'pitched down 20-35 degrees): one person, with MediaPipe in the same run, and three',
        MOUNTED_TESTS, lambda c: [_eval(c, str(DATA / s), RESULTS / f'{s}.json', '--model',
                                        'rgbd_14', *_people(s), peer=s == MOUNTED_TESTS[0])
                                  for s in MOUNTED_TESTS]),
    Job('lspet', 'LSPET photographs 2501-3000: the photograph network, the photograph part '
        "model, and the nodes' rgbd_14 by its colour channel alone, without and with the "
        'photograph network in its colour unary (the weights chosen on validation)', (),
        _lspet, needs='lspet'),
    Job('colour_net_test', "the held-out RGB-D sets with the photograph network in the "
        "detector's colour unary at the weights chosen on validation (the nodes' default) and "
        'without it, in the same run',
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
                       for name, net in (('bench_colour_net_none.json',
                                          ['--colour-net', 'none']),
                                         ('bench_colour_net.json',
                                          ['--colour-net', COLOUR_NET]))]),
    Job('bench_graph', 'the node graph on the demo bag: frames in and out, latency', (),
        lambda c: [['pose4d', 'bench', 'bags/sample', '--json',
                    str(RESULTS / 'bench_graph.json'), '--frames', '20', '--graph']]),
    Job('bench_graph300', 'both graphs replaying 300 frames at 30 fps (1x) while the ros2 command '
        'line queries the nodes (topic hz, param get), three runs each: frames in and out, '
        "latency, each graph's CPU a frame against the core's and MediaPipe's (the README's "
        'headline cost)',
        ('bench300',), lambda c: [['pose4d', 'bench', str(DATA / 'bench300_bag'), '--json',
                                   str(RESULTS / 'bench_graph300.json'), '--frames', '20',
                                   '--graph', '--load', 'query', '--repeat', '3',
                                   *(['--peer', 'mediapipe'] if c.peer else [])]]),
    Job('bench_graph300_quiet', 'bench_graph300 with nothing else running (no query load: '
        "each ros2 command is a new DDS participant whose discovery every node's DDS threads "
        'pay)', ('bench300',),
        lambda c: [['pose4d', 'bench', str(DATA / 'bench300_bag'), '--json',
                    str(RESULTS / 'bench_graph300_quiet.json'), '--frames', '20', '--graph',
                    '--repeat', '3', *(['--peer', 'mediapipe'] if c.peer else [])]]),
    Job('bench_graph_people2', 'both graphs replaying the two-person demo bag '
        '(bags/sample_people2, 50 frames) at 30 fps (1x): frames in and out, latency', (),
        lambda c: [['pose4d', 'bench', 'bags/sample_people2', '--json',
                    str(RESULTS / 'bench_graph_people2.json'), '--frames', '20', '--graph']]),
)
JOB_NAMES = tuple(j.name for j in JOBS)
