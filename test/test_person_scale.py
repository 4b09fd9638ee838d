"""The person's scale per track (core/dpm/scale.py) and the detector's scale factor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pose4d_ros.core.dpm.scale import PersonScale, ScaleConfig

CFG = ScaleConfig(factors=(0.8, 1.0, 1.25), warm_up_frames=3, probe_every=4)


def _run(scale: PersonScale, score_of, frames: int, t0: float = 0.0) -> list:
    """Frames at 30 fps: what was searched and what was used in each."""
    out = []
    for k in range(frames):
        factors = scale.factors(t0 + k / 30)
        used = scale.update({f: score_of(f) for f in factors})
        out.append((factors, used))
    return out


def test_the_best_scoring_factor_wins_after_the_warm_up_and_neighbours_are_probed():
    scale = PersonScale(CFG)
    rng = np.random.default_rng(0)
    # the person is 1.25x the model's size: its pose scores best there, noisily
    out = _run(scale, lambda f: -abs(math.log(f / 1.25)) + rng.normal(0, 0.05), 20)
    assert all(searched == CFG.factors for searched, _ in out[:3])  # the warm-up: all
    assert all(used == 1.25 for _, used in out[3:])
    searched = [s for s, _ in out[3:]]
    assert sum(len(s) == 2 for s in searched) == 4  # every 4th frame one neighbour too
    assert all(s in ((1.25,), (1.25, 1.0)) for s in searched)


def test_a_first_choice_is_corrected_by_the_probes():
    scale = PersonScale(CFG)
    # the first frames favour 1.25 (say, an arm raised), then 1.0 is clearly better
    out = _run(scale, lambda f: 1.0 if f == 1.25 else 0.0, 3)
    assert out[-1][1] == 1.25
    out = _run(scale, lambda f: {0.8: 0.0, 1.0: 3.0, 1.25: 1.0}[f], 30, t0=0.1)
    assert out[-1][1] == 1.0


def test_a_gap_or_time_going_back_starts_a_new_track():
    scale = PersonScale(CFG)
    _run(scale, lambda f: f, 9)
    assert scale.factors(9 / 30) == (1.25,)
    assert scale.factors(5.0) == CFG.factors  # 5 s later: a new person, warm up again
    scale.update({f: 0.0 for f in CFG.factors})
    assert scale.factors(1.0) == CFG.factors  # back in time: new track


def test_nothing_found_at_the_chosen_factor_uses_what_was_found():
    scale = PersonScale(CFG)
    _run(scale, lambda f: f, 3)
    scale.factors(0.2)
    assert scale.update({1.25: math.nan}) == 1.25  # nothing anywhere: the caller gives up
    assert scale.update({1.25: math.nan, 1.0: 0.5}) == 1.0


@pytest.mark.parametrize('bad', [{'factors': ()}, {'factors': (1.0, 0.8)},
                                 {'factors': (1.0, 9.0)}, {'warm_up_frames': 0},
                                 {'forget': 0.0}, {'max_gap_s': 0.0}])
def test_bad_configuration_is_refused(bad: dict):
    with pytest.raises(ValueError):
        ScaleConfig(**bad)


def test_a_few_frames_without_the_person_keep_the_track():
    scale = PersonScale(CFG)
    _run(scale, lambda f: f, 9)
    for k in range(9, 14):  # 5 frames (0.17 s) in which the person is not found
        scale.factors(k / 30)
    assert scale.factors(14 / 30) == (1.25,)
    scale.update({1.25: 1.0})
    for k in range(15, 45):  # then a whole second without the person: a new track
        scale.factors(k / 30)
    assert scale.factors(45 / 30) == CFG.factors
