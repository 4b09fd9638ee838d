"""Which real motion a synthetic set is made of: `pose4d synth --takes` and `--actions`
over the UTKinect takes ('sNN_eMM') and MSR Action3D sequences ('aAA_sSS_eEE') available."""

from __future__ import annotations

import re

_TAKE = re.compile(r'^s(\d{2})_e(\d{2})$')
_MSR_TAKE = re.compile(r'^a(\d{2})_s(\d{2})_e(\d{2})$')
# subject and take of a take name: UTKinect 'sNN_eMM' or MSR Action3D 'aAA_sSS_eEE'
_FIELDS = re.compile(r'(?:^|_)s(\d{2})_e(\d{2})$')
_SUBJECT = re.compile(r'^s(\d{2})$')
_RANGE = re.compile(r'^s(\d{2})-s(\d{2})$')


def parse_takes(spec: str, available: list[str]) -> list[str]:
    """Expand a --takes value into take names, in order, without repeats.

    `available` lists the takes present ('sNN_eMM'); every requested one must be there.
    """
    if spec.strip() == 'all':
        if not available:
            raise ValueError('no joints_sNN_eMM.txt files in the UTKinect directory')
        return sorted(available)
    out: list[str] = []
    for item, names in match_takes(spec, available).items():
        if not names or any(n not in available for n in names):
            missing = [n for n in names if n not in available] or [item]
            raise ValueError(f'--takes: no UTKinect take for {", ".join(missing)}')
        out += [n for n in names if n not in out]
    return out


def match_takes(spec: str, available: list[str]) -> dict[str, list[str]]:
    """Each item of a --takes value (not 'all') and the take names it stands for.

    Names are UTKinect's 'sNN_eMM' or MSR Action3D's 'aAA_sSS_eEE'. sNN_eMM stands for that
    UTKinect take, which need not be in `available`, and for take MM of every MSR Action3D
    action of subject NN; aAA_sSS_eEE for that sequence (even if not available); sNN and
    sNN-sMM for every available take of those subjects.
    """
    fields = {t: (int(m.group(1)), int(m.group(2)))
              for t in available if (m := _FIELDS.search(t))}
    out: dict[str, list[str]] = {}
    for item in (s.strip() for s in spec.split(',')):
        if m := _TAKE.match(item):
            key = (int(m.group(1)), int(m.group(2)))
            names = [item] + sorted(t for t, f in fields.items()
                                    if f == key and _MSR_TAKE.match(t))
        elif _MSR_TAKE.match(item):
            names = [item]
        elif m := _SUBJECT.match(item):
            names = sorted(t for t, f in fields.items() if f[0] == int(m.group(1)))
        elif m := _RANGE.match(item):
            lo, hi = int(m.group(1)), int(m.group(2))
            if lo > hi:
                raise ValueError(f'--takes: empty subject range {item!r}')
            names = sorted(t for t, f in fields.items() if lo <= f[0] <= hi)
        else:
            raise ValueError(f"--takes: {item!r} is not sNN_eMM, sNN, sNN-sMM or aAA_sSS_eEE")
        out[item] = names
    return out


def select_sources(takes: str, actions: str | None, utkinect: list[str], msr: list[str]
                   ) -> tuple[list[str], list[str]]:
    """The UTKinect takes and MSR Action3D sequences a run uses (names, sorted as asked).

    `utkinect`, `msr`: the names available in each source given. Every --takes item must stand
    for a take of one source at least; --actions items that name MSR Action3D actions (a01-a20
    or their names) keep only those sequences (none named: no MSR Action3D sequence).
    """
    from pose4d_ros.datasets.msraction3d import action_number

    if takes.strip() == 'all':
        ut, ms = sorted(utkinect), sorted(msr)
    else:
        ut, ms = [], []
        for item, names in match_takes(takes, utkinect + msr).items():
            found_ut = [n for n in names if n in utkinect]
            found_ms = [n for n in names if n in msr]
            if not found_ut and not found_ms:
                source = 'UTKinect take' if not msr else 'MSR Action3D sequence' if not \
                    utkinect else 'UTKinect take or MSR Action3D sequence'
                raise ValueError(f'--takes: no {source} for {item}')
            ut += [n for n in found_ut if n not in ut]
            ms += [n for n in found_ms if n not in ms]
    if actions is not None:
        wanted = set()
        for a in actions.split(','):
            try:
                wanted.add(action_number(a))
            except ValueError:
                continue  # a UTKinect action
        ms = [n for n in ms if int(n[1:3]) in wanted]
    return ut, ms


def plan_actions(actions: str | None) -> list[str] | None:
    """--actions for `video.plan_videos`: MSR Action3D actions given as a01-a20 by name."""
    from pose4d_ros.datasets.msraction3d import ACTIONS, action_number

    if actions is None:
        return None
    out = []
    for a in (x.strip() for x in actions.split(',')):
        try:
            out.append(ACTIONS[action_number(a) - 1])
        except ValueError:
            out.append(a)
    return out
