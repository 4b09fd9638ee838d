"""A set of named joints of one person in one frame: the core-side twin of JointArray.

`nodes/convert.py` turns it into a `pose4d_msgs/JointArray` and back; everything else works on
this dataclass. Unknown values are NaN. Source codes equal the message's constants (a test
checks it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

DETECTED = 0  # measured by the part detector in this frame
TRACKED = 1  # estimated by the tracker
INFERRED = 2  # inferred by inverse kinematics
MISSING = 3  # no estimate

SOURCE_NAMES = {DETECTED: 'detected', TRACKED: 'tracked', INFERRED: 'inferred', MISSING: 'missing'}


@dataclass(frozen=True, eq=False)
class JointSet:
    """Joints of one person in one image.

    Attributes
    ----------
    names : J joint names (core.skeleton).
    uv : (J, 2) float64 pixel (u, v) in the colour image; NaN = unknown.
    xyz : (J, 3) float64 metres, camera optical frame; NaN = no depth.
    confidence : (J,) float32 in [0, 1].
    source : (J,) uint8, DETECTED / TRACKED / INFERRED / MISSING.
    covariance : (J, 3, 3) float64 square metres; zeros = unknown.
    score : whole-pose score (model score for detections, 0..1 for tracks); NaN = unknown.
    track_id : 0 = untracked.
    """

    names: tuple[str, ...]
    uv: NDArray[np.float64]
    xyz: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    confidence: NDArray[np.float32] = field(default=None)  # type: ignore[assignment]
    source: NDArray[np.uint8] = field(default=None)  # type: ignore[assignment]
    covariance: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    score: float = float('nan')
    track_id: int = 0

    def __post_init__(self) -> None:
        n = len(self.names)
        uv = np.array(self.uv, dtype=np.float64).reshape(n, 2)
        xyz = (np.full((n, 3), np.nan) if self.xyz is None
               else np.array(self.xyz, dtype=np.float64).reshape(n, 3))
        finite = np.isfinite(uv).all(axis=1)
        conf = (finite.astype(np.float32) if self.confidence is None
                else np.array(self.confidence, dtype=np.float32).reshape(n))
        src = (np.where(finite, DETECTED, MISSING).astype(np.uint8) if self.source is None
               else np.array(self.source, dtype=np.uint8).reshape(n))
        cov = (np.zeros((n, 3, 3)) if self.covariance is None
               else np.array(self.covariance, dtype=np.float64).reshape(n, 3, 3))
        if np.any(src > MISSING):
            raise ValueError(f'unknown joint source code(s) {sorted(set(src[src > MISSING]))}')
        for name, arr in (('uv', uv), ('xyz', xyz), ('confidence', conf), ('source', src),
                          ('covariance', cov)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, 'names', tuple(self.names))

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def get(self, name: str) -> int | None:
        """Index of a joint, None if absent."""
        return self.names.index(name) if name in self.names else None

    def with_(self, **changes: object) -> JointSet:
        """A copy with some fields replaced."""
        return replace(self, **changes)

    @classmethod
    def missing(cls, names: tuple[str, ...] | list[str]) -> JointSet:
        """All joints MISSING."""
        n = len(names)
        return cls(tuple(names), np.full((n, 2), np.nan), confidence=np.zeros(n),
                    source=np.full(n, MISSING))
