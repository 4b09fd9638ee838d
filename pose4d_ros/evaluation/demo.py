"""What `pose4d demo` makes of one replay of a bag through the node graph: the recorded
skeletons read back, scored against the bag's ground truth beside the same core run offline
over the same bag, and drawn.

A bag with one person's ground truth (`/cad60/skeleton`, `bags/sample`) is scored as `pose4d
eval` scores a single-person set: the recorded `/pose4d/skeleton` against it, the offline rows
from the single-person pipeline. A bag with every person's ground truth (`/cad60/skeletons`,
`bags/sample_people2`) is scored as a several-person set (`pipeline.score_rows`): each frame's
people matched one to one to the recorded `/pose4d/skeletons` (one JointArray per person, its
`track_id`), the table pooled over people plus `tracking` (IDF1, MOTA, id switches, ...), the
offline rows from the several-person pipeline (`TrackingConfig()`, as the nodes run it); and
per person (`per_person`): PCK@0.1 average7 over the frames the person is labelled in and the
track ids the person was given.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.files import write_atomic
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.metrics import score_joint_sets
from pose4d_ros.core.people import TrackingConfig
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.datasets import bag
from pose4d_ros.datasets.frame import Frame
from pose4d_ros.evaluation.draw import overlay_frame, overlay_picture, write_video
from pose4d_ros.evaluation.pipeline import (
    Row,
    ms_stats,
    people_scores,
    pipeline_rows,
    row_names,
    score_rows,
)
from pose4d_ros.evaluation.tables import colour_unary, format_table
from pose4d_ros.wire import joints_from_msg, stamp_to_ns

LIVE = 'graph'  # the live row's name in the tables
SKELETON_TOPIC = '/pose4d/skeleton'
SKELETONS_TOPIC = '/pose4d/skeletons'


@dataclass(frozen=True)
class Recording:
    """What the graph put out, by colour-frame stamp: the primary person's skeleton
    (`/pose4d/skeleton`) and everyone's (`/pose4d/skeletons`; empty where not recorded)."""

    skeleton: dict[int, JointSet]
    people: dict[int, tuple[JointSet, ...]]


def read_recording(recorded: Path) -> Recording:
    """The skeletons of a recorded run (the first message of each stamp)."""
    skeleton: dict[int, JointSet] = {}
    people: dict[int, tuple[JointSet, ...]] = {}
    topics = [t for t in (SKELETON_TOPIC, SKELETONS_TOPIC) if t in bag.topics(recorded)]
    for m in bag.read_messages(recorded, topics):
        msg = bag.deserialize(m)
        stamp = stamp_to_ns(msg.header.stamp)
        if m.topic == SKELETON_TOPIC:
            skeleton.setdefault(stamp, joints_from_msg(msg))
        else:
            people.setdefault(stamp, tuple(joints_from_msg(s) for s in msg.skeletons))
    return Recording(skeleton, people)


def several_people(frames: Sequence[Frame]) -> bool:
    """The frames hold every person's ground truth (`Frame.people`)."""
    return any(f.people for f in frames)


def live_row(frames: Sequence[Frame], rec: Recording) -> Row:
    """The recorded skeletons as a row over the frames (all MISSING / nobody where a frame
    gave none); with several people, everyone's too (`Row.people`)."""
    row, several = Row(), several_people(frames)
    for f in frames:
        row.preds.append(rec.skeleton.get(f.stamp_ns, JointSet.missing(SKELETON_14)))
        if several:
            row.people.append(rec.people.get(f.stamp_ns, ()))
    return row


def per_person(name: str, row: Row, frames: Sequence[Frame]) -> dict[str, dict]:
    """Each ground-truth person's scores in a row: {person id: {'average7': PCK@0.1 average7
    over the frames the person is labelled in (a frame without a skeleton matched: every joint
    wrong), 'frames': those frames, 'tracks': {track id: frames matched to it}, 'missed':
    frames matched to none}}, by the matching of `score_rows` (`pipeline.people_scores`)."""
    names = row_names(name, row)
    out = people_scores(row, frames, names)
    preds, truths = out['matched']
    by_person: dict[int, list[int]] = {}
    for i, truth in enumerate(truths):
        by_person.setdefault(int(truth.track_id), []).append(i)
    scores = {}
    for pid, idx in sorted(by_person.items()):
        sizes = [(frames[out['frames'][i]].color.shape[1], frames[out['frames'][i]].color.shape[0])
                 for i in idx]
        table = score_joint_sets([preds[i] for i in idx], [truths[i] for i in idx], names,
                                 image_sizes=sizes)
        tracks = Counter(int(preds[i].track_id) for i in idx if preds[i] is not None)
        scores[str(pid)] = {'average7': table['pck']['average7'], 'frames': len(idx),
                            'tracks': {str(t): n for t, n in sorted(tracks.items())},
                            'missed': sum(preds[i] is None for i in idx)}
    return scores


def score_run(frames: Sequence[Frame], rec: Recording, model: PartModel) -> dict:
    """{'graph': the live row's table, 'offline': the offline rows' tables} (`score_rows`), and
    with several people 'people': {'graph': `per_person` of the live row, 'offline': of the
    offline `_kf_ik` row}."""
    several = several_people(frames)
    live = live_row(frames, rec)
    # the nodes' default detector: the photograph network in the colour unary
    offline = pipeline_rows(frames, model, people=TrackingConfig() if several else None,
                            unary=colour_unary())
    tables = score_rows({LIVE: live, **offline}, frames)
    out = {LIVE: tables.pop(LIVE), 'offline': tables}
    if several:
        skeleton = next(k for k in offline if k.endswith('_kf_ik'))
        out['people'] = {LIVE: per_person(LIVE, live, frames),
                         'offline': per_person(skeleton, offline[skeleton], frames)}
    return out


# The first frames of a run, whose latency `run_results` also gives alone (a new track
# searches every person scale: `core.dpm.scale.ScaleConfig.warm_up_frames`)
FIRST_FRAMES = 5


def run_results(frames_in: int, rec: Recording, latency_ms: dict[int, float], scores: dict,
                **facts: object) -> dict:
    """results.json's entry of one run: `facts` (bag, rate, ...), frames in and out, the
    latency (p50, p95 of `latency_ms`, {stamp: ms} colour frame in -> skeleton out; and the
    first `FIRST_FRAMES` frames' own, where a short run's tail is), then `score_run`'s
    `scores`."""
    out = len(rec.skeleton)
    ordered = [latency_ms[s] for s in sorted(latency_ms)]
    return {**facts, 'frames_in': frames_in, 'skeletons_out': out,
            'frames_lost': frames_in - out,
            **({'people_arrays_out': len(rec.people)} if 'people' in scores else {}),
            'latency_ms': {**ms_stats(ordered), 'n': len(ordered),
                           'first_frames': [round(v, 1) for v in ordered[:FIRST_FRAMES]],
                           'after_first': ms_stats(ordered[FIRST_FRAMES:])}
            if latency_ms else None, **scores}


def format_run(results: dict) -> str:
    """The printout of `run_results` (with its 'tf': `graph.run.tf_per_skeleton`): the tables,
    per person (several people), frames in and out, latency, /tf."""
    scores = {'graph (live, rgbd+kf+ik)': results[LIVE],
              **{f'offline {k}': v for k, v in results['offline'].items()}}
    lines = [format_table(scores, results['frames_in'])]
    if 'people' in results:
        lines += ['', format_people(results)]
    lines += ['', f'frames in {results["frames_in"]} (replayed at '
              f'{results["input_rate_hz"]:.1f} Hz), skeletons out {results["skeletons_out"]}, '
              f'lost {results["frames_lost"]}']
    if results['latency_ms']:
        lat = results['latency_ms']
        lines.append(f'latency colour frame -> /pose4d/skeleton: p50 {lat["p50"]:.1f} ms, '
                     f'p95 {lat["p95"]:.1f} ms (n = {lat["n"]})')
        after = lat['after_first']
        if after['p95'] is not None:
            lines.append(f'  the first {len(lat["first_frames"])} frames: '
                         f'{", ".join(f"{v:.0f}" for v in lat["first_frames"])} ms (a new '
                         f"track's scales searched); after them p50 {after['p50']:.1f} ms, "
                         f'p95 {after["p95"]:.1f} ms')
    tf = results['tf']
    lines.append(f'/tf: {tf["transforms"]} transforms, one per located joint, stamped like the '
                 f'skeleton, for {tf["matching"]} of {tf["skeletons"]} skeletons')
    return '\n'.join(lines)


def format_people(scores: dict) -> str:
    """The per-person lines of `score_run`'s result (with several people), and the id
    switches and IDF1 of the live and the offline skeleton rows."""
    offline = next(k for k in scores['offline'] if k.endswith('_kf_ik'))
    lines = ['per person: PCK@0.1 average7 over the frames the person is in, and the track ids '
             'given (frames each)']
    for pid, live in scores['people'][LIVE].items():
        off = scores['people']['offline'].get(pid, {})
        lines.append(f'  person {pid} ({live["frames"]} frames): live {live["average7"]:.1f} '
                     f'{_ids(live)}; offline {off.get("average7", float("nan")):.1f} '
                     f'{_ids(off)}')
    t_live, t_off = scores[LIVE]['tracking'], scores['offline'][offline]['tracking']
    lines.append(f'id switches: live {t_live["id_switches"]:.0f}, offline '
                 f'{t_off["id_switches"]:.0f}; IDF1 live {100 * t_live["idf1"]:.1f} %, offline '
                 f'{100 * t_off["idf1"]:.1f} %; false skeletons live '
                 f'{t_live["false_positives"]:.0f}, offline {t_off["false_positives"]:.0f}')
    return '\n'.join(lines)


def _ids(person: dict) -> str:
    ids = ', '.join(f'{t}: {n}' for t, n in person.get('tracks', {}).items()) or 'none'
    missed = f', missed {person["missed"]}' if person.get('missed') else ''
    return f'(ids {ids}{missed})'


def write_overlays(out: Path, stem: str, frames: Sequence[Frame], rec: Recording,
                   latency_ms: dict[int, float], *, fps: float) -> int:
    """`<stem>.mp4`, one video frame per skeleton out (with several people, every person's
    skeleton with its bones in its track id's colour) and `<stem>.png` (four frames of the
    bag); returns the video's frames."""
    frames = list(frames)
    live = live_row(frames, rec)
    people = live.people if several_people(frames) else None
    overlay = overlay_picture(frames, live.preds, people=people)
    ok, png = cv2.imencode('.png', np.ascontiguousarray(overlay[:, :, ::-1]))
    if not ok:
        raise ValueError(f'could not encode the overlay picture ({overlay.shape})')
    write_atomic(out / f'{stem}.png', png.tobytes())
    shown = [(f, rec.skeleton[f.stamp_ns], latency_ms.get(f.stamp_ns),
              None if people is None else rec.people.get(f.stamp_ns, ()))
             for f in frames if f.stamp_ns in rec.skeleton]
    return write_video(out / f'{stem}.mp4', (overlay_frame(*x) for x in shown), fps=fps)
