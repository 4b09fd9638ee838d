"""The person's own scale, per track, chosen by the part model's pose score.

Depth gives the person's scale in pixels as fx * L / z for a body of the size the model was
trained on (`PartModel.scale_length_m`), so a person much taller or shorter than the training
bodies (or one whose shoulders are raised with the arms) is searched at the wrong scale, and
the springs then pull the legs up into the knees (measured on the bundled demo bag: a 1.95 m
person whose torso is 1.35x the training median). A person's body does not change while they
are tracked, so their scale factor is a constant of the track: each of a few factors around
1 (`ScaleConfig.factors`) is searched in the first frames of a track, and the one whose pose
scores highest on average wins; after that one level is searched per frame, its neighbours
being probed now and then (`probe_every`) so that a first choice made on a few frames can
still change. A single frame's best score across levels is a noisy choice (it loses on the
held-out sets); the average over frames is not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ScaleConfig:
    """How the person's scale factor is chosen (see the module docstring).

    Attributes
    ----------
    factors : candidate factors on the depth-predicted person scale, ascending (a factor > 1:
        a person larger than the model's training bodies; by default steps of 2^0.2, the
        detector's level step: 0.87, 1, 1.15, chosen on validation, valid30 and valid30_msr,
        over 0.87-1.32 as first shipped, 0.76-1.52 and 1 alone; `make results`). (1.0,) turns
        the choice off.
    warm_up_frames : frames at the start of a track in which every factor is searched (2,
        chosen on validation by `make results`' `person_scale` sweep over 4, shipped before,
        and 8: as accurate pooled over valid30, valid30_msr and valid60_people2, 93.39 against
        93.31 and 93.32, with 8.7 % less search work than 4; refused before the detector's
        occlusion floor for its false skeletons on valid60_people2, 33.3 per 1000 frames,
        none since).
    probe_every : after the warm-up, one neighbour of the chosen factor is also searched
        every this many frames (0 = never, shipped: chosen on validation by `make results`
        over 8, shipped before, and 16: as accurate, pooled over valid30, valid30_msr and
        valid60_people2, with 7.7 % less search work; a person's scale is settled by the
        warm-up's frames).
    forget : weight of a new score in a factor's running mean after the warm-up.
    max_gap_s : a longer gap between frames starts a new track (a new person).
    """

    factors: tuple[float, ...] = (0.87, 1.0, 1.15)
    warm_up_frames: int = 2
    probe_every: int = 0
    forget: float = 0.2
    max_gap_s: float = 0.5

    def __post_init__(self) -> None:
        f = self.factors
        if not f or any(not 0.25 <= x <= 4.0 for x in f) or list(f) != sorted(set(f)):
            raise ValueError(f'factors must be ascending, distinct, within 0.25..4, got {f}')
        if self.warm_up_frames < 1 or self.probe_every < 0:
            raise ValueError(f'warm_up_frames must be >= 1 and probe_every >= 0, got '
                             f'{self.warm_up_frames}, {self.probe_every}')
        if not 0.0 < self.forget <= 1.0:
            raise ValueError(f'forget must be in (0, 1], got {self.forget}')
        if not self.max_gap_s > 0:
            raise ValueError(f'max_gap_s must be > 0, got {self.max_gap_s}')


class PersonScale:
    """The scale factor of the tracked person: `factors(stamp)` says which factors to search
    in a frame, `update(scores)` takes their best pose scores and returns the factor whose pose
    to use. A frame without the person (no `update`) changes nothing: the track ends when
    the person has not been seen for `max_gap_s`, or on `reset()`."""

    def __init__(self, config: ScaleConfig | None = None) -> None:
        self.config = config or ScaleConfig()
        self.reset()

    def reset(self) -> None:
        self.mean: dict[float, float] = {}
        self.frames = 0
        self.seen: float | None = None  # when the person was last seen
        self.stamp: float | None = None  # this frame's time
        self.chosen = 1.0 if 1.0 in self.config.factors else self.config.factors[0]

    def factors(self, stamp_s: float | None = None) -> tuple[float, ...]:
        """The factors to search in this frame (more than `max_gap_s` since the person was
        last seen, or time going back, starts a new track first)."""
        cfg = self.config
        if stamp_s is not None and self.seen is not None and \
                not 0.0 <= stamp_s - self.seen <= cfg.max_gap_s:
            self.reset()
        self.stamp = stamp_s
        if self.frames < cfg.warm_up_frames:
            return cfg.factors
        k = self.frames - cfg.warm_up_frames + 1
        if cfg.probe_every and k % cfg.probe_every == 0:
            i = cfg.factors.index(self.chosen)
            near = [cfg.factors[j] for j in (i - 1, i + 1) if 0 <= j < len(cfg.factors)]
            if near:
                return (self.chosen, near[(k // cfg.probe_every) % len(near)])
        return (self.chosen,)

    def update(self, scores: dict[float, float]) -> float:
        """Take the best pose score found at each searched factor (NaN: nothing found) and
        return the factor whose pose to use now: the best running mean among those found now
        (the chosen factor, unless it found nothing in this frame)."""
        warm = self.frames < self.config.warm_up_frames
        now = [f for f, s in scores.items() if math.isfinite(s)]
        if now and self.stamp is not None:
            self.seen = self.stamp
        for f in now:
            old = self.mean.get(f)
            # the plain mean while warming up (every factor searched), then a running mean
            w = 1.0 if old is None else (1.0 / (self.frames + 1) if warm
                                         else self.config.forget)
            self.mean[f] = scores[f] if old is None else old + w * (scores[f] - old)
        self.frames += 1
        if self.mean:
            self.chosen = max(self.mean, key=self.mean.__getitem__)
        if not now or self.chosen in now:
            return self.chosen
        return max(now, key=self.mean.__getitem__)
