"""Joint names, part trees and joint groups shared by every stage.

Conventions (the one place they are defined):

- Left and right are the person's own (anatomical) sides everywhere in the project. Datasets
  whose labels are mirrored are corrected in their reader, nowhere else.
- Names follow CAD-60 (`head`, `neck`, `torso`, `left_shoulder`, ...). The detector and the
  published skeleton name the end of the arm `*_wrist` and the end of the leg `*_ankle`; CAD-60
  (OpenNI) calls the nearest joints `*_hand` and `*_foot`. `GROUND_TRUTH_ALIASES` maps one to
  the other when scoring.
- A part tree is a tuple of parent indices (`-1` for the root), parents before children.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

# CAD-60 skeleton files, joints 1..15 in file order (Kinect v1 / OpenNI).
CAD60_JOINTS: tuple[str, ...] = (
    'head', 'neck', 'torso',
    'left_shoulder', 'left_elbow', 'right_shoulder', 'right_elbow',
    'left_hip', 'left_knee', 'right_hip', 'right_knee',
    'left_hand', 'right_hand', 'left_foot', 'right_foot',
)

# The 14-joint skeleton published on pose4d/skeleton (the paper's output after IK).
SKELETON_14: tuple[str, ...] = (
    'head', 'neck',
    'left_shoulder', 'left_elbow', 'left_wrist',
    'right_shoulder', 'right_elbow', 'right_wrist',
    'left_hip', 'left_knee', 'left_ankle',
    'right_hip', 'right_knee', 'right_ankle',
)

# Scoring a prediction named like SKELETON_14 against CAD-60 ground truth.
GROUND_TRUTH_ALIASES: dict[str, str] = {
    'left_wrist': 'left_hand', 'right_wrist': 'right_hand',
    'left_ankle': 'left_foot', 'right_ankle': 'right_foot',
}

# Joint groups of the paper's tables (left and right pooled), in table order.
JOINT_GROUPS: dict[str, tuple[str, ...]] = {
    'head': ('head',),
    'shoulder': ('left_shoulder', 'right_shoulder'),
    'elbow': ('left_elbow', 'right_elbow'),
    'wrist': ('left_wrist', 'right_wrist'),
    'hip': ('left_hip', 'right_hip'),
    'knee': ('left_knee', 'right_knee'),
    'ankle': ('left_ankle', 'right_ankle'),
}

# The groups averaged in the paper's Tables 2 and 3 (the reduced model's joints).
TABLE_GROUPS: tuple[str, ...] = ('head', 'shoulder', 'wrist', 'hip', 'ankle')

# Arm and leg chains completed by inverse kinematics: (root, middle, end).
LIMBS: dict[str, tuple[str, str, str]] = {
    'left_arm': ('left_shoulder', 'left_elbow', 'left_wrist'),
    'right_arm': ('right_shoulder', 'right_elbow', 'right_wrist'),
    'left_leg': ('left_hip', 'left_knee', 'left_ankle'),
    'right_leg': ('right_hip', 'right_knee', 'right_ankle'),
}


@dataclass(frozen=True)
class PartTree:
    """A tree of named parts: `parents[i]` is the index of part i's parent, -1 for the root.

    Parents come before their children, so a reversed loop over the parts visits children
    before parents (message passing to the root) and a forward loop does the opposite
    (backtracking).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]

    def __post_init__(self) -> None:
        if len(self.names) != len(self.parents):
            raise ValueError(f'{len(self.names)} names but {len(self.parents)} parents')
        if len(set(self.names)) != len(self.names):
            raise ValueError(f'duplicate part names in {self.names}')
        roots = [i for i, p in enumerate(self.parents) if p == -1]
        if roots != [0]:
            raise ValueError(f'part 0 must be the only root, got roots {roots}')
        for i, p in enumerate(self.parents[1:], start=1):
            if not 0 <= p < i:
                raise ValueError(f'parent {p} of part {i} ({self.names[i]}) is not before it')

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def edges(self) -> list[tuple[int, int]]:
        """(parent, child) index pairs."""
        return [(p, i) for i, p in enumerate(self.parents) if p >= 0]

    def children(self, i: int) -> list[int]:
        return [c for c, p in enumerate(self.parents) if p == i]


def _tree(edges: list[tuple[str, str]], root: str) -> PartTree:
    names = [root]
    parents = [-1]
    for parent, child in edges:
        parents.append(names.index(parent))
        names.append(child)
    return PartTree(tuple(names), tuple(parents))


# The paper's reduced 10-part model: head, neck, shoulders, wrists, hips, ankles. The neck is
# the root; a hip hangs from the shoulder of its side (the torso's side, as in Yang & Ramanan).
PARTS_10 = _tree(
    [
        ('neck', 'head'),
        ('neck', 'left_shoulder'), ('left_shoulder', 'left_wrist'),
        ('neck', 'right_shoulder'), ('right_shoulder', 'right_wrist'),
        ('left_shoulder', 'left_hip'), ('left_hip', 'left_ankle'),
        ('right_shoulder', 'right_hip'), ('right_hip', 'right_ankle'),
    ],
    root='neck',
)

# The full 14-part model (elbows and knees detected too).
PARTS_14 = _tree(
    [
        ('neck', 'head'),
        ('neck', 'left_shoulder'), ('left_shoulder', 'left_elbow'), ('left_elbow', 'left_wrist'),
        ('neck', 'right_shoulder'), ('right_shoulder', 'right_elbow'),
        ('right_elbow', 'right_wrist'),
        ('left_shoulder', 'left_hip'), ('left_hip', 'left_knee'), ('left_knee', 'left_ankle'),
        ('right_shoulder', 'right_hip'), ('right_hip', 'right_knee'),
        ('right_knee', 'right_ankle'),
    ],
    root='neck',
)

# Limb midpoints, parts of the 22-part model (as Yang & Ramanan's 26-part model places parts
# between the joints of a limb): the midpoint of the two joints named.
MIDPOINTS: dict[str, tuple[str, str]] = {
    f'{side}_{limb}': (f'{side}_{a}', f'{side}_{b}')
    for side in ('left', 'right')
    for limb, (a, b) in (('upper_arm', ('shoulder', 'elbow')), ('forearm', ('elbow', 'wrist')),
                         ('thigh', ('hip', 'knee')), ('shin', ('knee', 'ankle')))
}

# The 14 joints and a part in the middle of each limb bone: 22 parts.
PARTS_22 = _tree(
    [
        ('neck', 'head'),
        *[edge for side in ('left_', 'right_') for edge in (
            ('neck', side + 'shoulder'), (side + 'shoulder', side + 'upper_arm'),
            (side + 'upper_arm', side + 'elbow'), (side + 'elbow', side + 'forearm'),
            (side + 'forearm', side + 'wrist'))],
        *[edge for side in ('left_', 'right_') for edge in (
            (side + 'shoulder', side + 'hip'), (side + 'hip', side + 'thigh'),
            (side + 'thigh', side + 'knee'), (side + 'knee', side + 'shin'),
            (side + 'shin', side + 'ankle'))],
    ],
    root='neck',
)

PART_TREES: dict[str, PartTree] = {'10': PARTS_10, '14': PARTS_14, '22': PARTS_22}


def tree_for(names: tuple[str, ...] | list[str]) -> PartTree:
    """The smallest part tree holding every one of `names` that it can (the 10-part tree for
    its own parts or fewer, the 14-part tree once elbows or knees are among them)."""
    given = set(names)
    return max(PART_TREES.values(), key=lambda t: (len(given & set(t.names)), -len(t)))


def group_of(name: str) -> str | None:
    """The table group of a joint name (`'left_wrist'` -> `'wrist'`), None if not scored."""
    for group, members in JOINT_GROUPS.items():
        if name in members:
            return group
    return None


def ground_truth_name(name: str) -> str:
    """The CAD-60 name under which a predicted joint's ground truth is stored."""
    return GROUND_TRUTH_ALIASES.get(name, name)


def limb_bones() -> list[tuple[int, int]]:
    """Bones of the 14-joint skeleton as index pairs (for drawing)."""
    names = SKELETON_14
    bones = [(names.index('head'), names.index('neck'))]
    for root, middle, end in LIMBS.values():
        bones += [(names.index(root), names.index(middle)), (names.index(middle),
                                                              names.index(end))]
    for side in ('left', 'right'):
        bones.append((names.index('neck'), names.index(f'{side}_shoulder')))
        bones.append((names.index(f'{side}_shoulder'), names.index(f'{side}_hip')))
    bones.append((names.index('left_hip'), names.index('right_hip')))
    return bones


_LEFT_RIGHT = (('left_', 'right_'), ('right_', 'left_'))


def mirror_name(name: str) -> str:
    """'left_wrist' <-> 'right_wrist'; other names unchanged."""
    for a, b in _LEFT_RIGHT:
        if name.startswith(a):
            return b + name[len(a):]
    return name


def mirror_index(names: Sequence[str]) -> list[int]:
    """Index in `names` of each name's left/right counterpart (itself for the middle parts)."""
    names = list(names)
    return [names.index(mirror_name(n)) for n in names]
