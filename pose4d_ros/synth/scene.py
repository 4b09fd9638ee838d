"""Rooms for the synthetic people: textured oriented boxes (floor, walls, ceiling, skirting,
door, pictures, furniture, sometimes an occluder between camera and person) seen by a camera at
0.85-1.35 m, pitched down a little, lit by a directional light plus ambient (`random_scene`).

Rooms are built in a right-handed room frame: X right, Y forward (away from the camera), Z up,
floor at Z = 0, camera at (0, 0, h); `Scene.to_optical` maps room to optical.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.synth import textures as tex
from pose4d_ros.synth.raycast import raycast_boxes


def unit(v: NDArray[np.float64], fallback: NDArray[np.float64]) -> NDArray[np.float64]:
    """`v` scaled to length 1, or `fallback` when it has none."""
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 else fallback


@dataclass(frozen=True)
class Box:
    """An oriented box in the room frame (X right, Y forward, Z up; metres, radians)."""

    center: tuple[float, float, float]
    half: tuple[float, float, float]
    material: int
    yaw: float = 0.0
    kind: str = 'furniture'  # 'floor', 'wall', 'furniture', 'occluder', 'decor'


@dataclass(frozen=True, eq=False)
class Scene:
    """A furnished room, its camera and light, with the room pre-rendered for `intrinsics`.

    Attributes
    ----------
    intrinsics : the camera the background buffers were rendered for.
    cam_height_m : camera centre above the floor, metres.
    room_to_cam : (3, 3) float64 rotation, p_optical = room_to_cam @ (p_room - cam_pos).
    cam_pos : (3,) float64 room frame.
    boxes : the room's boxes; boxes[floor_index] is the floor.
    materials : the boxes' materials.
    light_room : (3,) unit vector towards the light, room frame.
    ambient, diffuse : shading weights; light_colour : (3,) RGB gain.
    bg_depth : (H, W) float32 z metres (inf = nothing); bg_normal (H, W, 3) float32;
    bg_albedo : (H, W, 3) float32; bg_ids : (H, W) int32 box index; bg_dropout : (H, W)
        float32 infrared dropout probability of the material seen.
    """

    intrinsics: Intrinsics
    cam_height_m: float
    room_to_cam: NDArray[np.float64]
    cam_pos: NDArray[np.float64]
    boxes: tuple[Box, ...]
    materials: tex.Materials
    light_room: NDArray[np.float64]
    ambient: float
    diffuse: float
    light_colour: NDArray[np.float64]
    floor_index: int
    bg_depth: NDArray[np.float32] = field(repr=False)
    bg_normal: NDArray[np.float32] = field(repr=False)
    bg_albedo: NDArray[np.float32] = field(repr=False)
    bg_ids: NDArray[np.int32] = field(repr=False)
    bg_dropout: NDArray[np.float32] = field(repr=False)

    @property
    def up_optical(self) -> NDArray[np.float64]:
        """(3,) the room's up direction in the optical frame."""
        return self.room_to_cam @ np.array([0.0, 0.0, 1.0])

    @property
    def light_optical(self) -> NDArray[np.float64]:
        return self.room_to_cam @ self.light_room

    def to_optical(self, points_room: NDArray[np.floating]) -> NDArray[np.float64]:
        """(..., 3) room frame -> optical frame, metres."""
        p = np.asarray(points_room, dtype=np.float64)
        return (p - self.cam_pos) @ self.room_to_cam.T

    def footprints(self, kinds: tuple[str, ...] = ('furniture', 'occluder')
                   ) -> NDArray[np.float64]:
        """(K, 4) floor rectangles (xmin, xmax, ymin, ymax) of the boxes of `kinds`."""
        out = []
        for b in self.boxes:
            if b.kind not in kinds:
                continue
            c, s = np.cos(b.yaw), np.sin(b.yaw)
            ex = abs(c) * b.half[0] + abs(s) * b.half[1]
            ey = abs(s) * b.half[0] + abs(c) * b.half[1]
            out.append((b.center[0] - ex, b.center[0] + ex, b.center[1] - ey,
                        b.center[1] + ey))
        return np.array(out, dtype=np.float64).reshape(-1, 4)

    def with_boxes(self, boxes: list[Box],
                   materials: tuple[tuple[str, NDArray[np.float32], float], ...] = ()
                   ) -> Scene:
        """A copy with more boxes (and materials, numbered after the existing ones)."""
        mats = self.materials
        if materials:
            mb = tex.MaterialBuilder()
            for i, name in enumerate(mats.names):
                mb.add(name, mats.tiles[i], tuple(mats.scale[i]), float(mats.ir_dropout[i]))
            for name, tile, scale in materials:
                mb.add(name, tile, scale)
            mats = mb.build()
        return _build_scene(self.intrinsics, self.cam_height_m, self.room_to_cam,
                            self.boxes + tuple(boxes), mats, self.light_room, self.ambient,
                            self.diffuse, self.light_colour, self.floor_index)

    def with_light(self, *, gain: float = 1.0, light_room: NDArray[np.floating] | None = None
                   ) -> Scene:
        """A copy with the light scaled by `gain` (and turned to `light_room`); no re-render."""
        lr = self.light_room if light_room is None else unit(np.asarray(light_room, float),
                                                              self.light_room)
        return replace(self, light_room=lr, light_colour=self.light_colour * gain)

    def for_intrinsics(self, intrinsics: Intrinsics) -> Scene:
        """The same room rendered for another camera model."""
        if intrinsics == self.intrinsics:
            return self
        return _build_scene(intrinsics, self.cam_height_m, self.room_to_cam, self.boxes,
                            self.materials, self.light_room, self.ambient, self.diffuse,
                            self.light_colour, self.floor_index)


def _yaw_matrix(yaw: float) -> NDArray[np.float64]:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def camera_rotation(pitch: float, yaw: float = 0.0, roll: float = 0.0) -> NDArray[np.float64]:
    """room_to_cam for a camera looking along +Y, pitched down by `pitch`, turned left by
    `yaw` and rolled by `roll` (radians); rows are the optical axes in the room frame."""
    cp, sp = np.cos(pitch), np.sin(pitch)
    x = np.array([1.0, 0.0, 0.0])
    z = np.array([0.0, cp, -sp])
    y = np.cross(z, x)
    rot = np.stack([x, y, z])  # rows: optical x, y, z in room coordinates
    cr, sr = np.cos(roll), np.sin(roll)
    roll_m = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return roll_m @ rot @ _yaw_matrix(yaw).T


def _build_scene(intrinsics: Intrinsics, cam_height: float, room_to_cam: NDArray[np.float64],
                 boxes: tuple[Box, ...], materials: tex.Materials, light_room, ambient: float,
                 diffuse: float, light_colour, floor_index: int) -> Scene:
    cam_pos = np.array([0.0, 0.0, cam_height])
    n = len(boxes)
    centers = np.empty((n, 3))
    rots = np.empty((n, 3, 3))
    halves = np.empty((n, 3))
    mats = np.empty(n, dtype=np.int64)
    for i, b in enumerate(boxes):
        centers[i] = room_to_cam @ (np.asarray(b.center) - cam_pos)
        # row k = local axis k (room: yaw about Z) expressed in the optical frame
        rots[i] = (room_to_cam @ _yaw_matrix(b.yaw)).T
        halves[i] = b.half
        mats[i] = b.material
    h, w = intrinsics.height, intrinsics.width
    depth = np.empty((h, w), np.float32)
    normal = np.empty((h, w, 3), np.float32)
    albedo = np.empty((h, w, 3), np.float32)
    ids = np.empty((h, w), np.int32)
    raycast_boxes(intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, h, w, centers,
                  rots, halves, mats, materials.tiles, materials.scale, depth, normal, albedo,
                  ids)
    dropout = np.where(ids >= 0, materials.ir_dropout[mats[np.maximum(ids, 0)]], 0.0)
    for a in (depth, normal, albedo, ids):
        a.flags.writeable = False
    return Scene(intrinsics=intrinsics, cam_height_m=cam_height, room_to_cam=room_to_cam,
                 cam_pos=cam_pos, boxes=boxes, materials=materials,
                 light_room=np.asarray(light_room, float), ambient=float(ambient),
                 diffuse=float(diffuse), light_colour=np.asarray(light_colour, float),
                 floor_index=floor_index, bg_depth=depth, bg_normal=normal, bg_albedo=albedo,
                 bg_ids=ids, bg_dropout=dropout.astype(np.float32))


# The region where `pose4d synth` puts people by default (2.4-3.4 m away): room-frame X and Y
# ranges, metres.
PERSON_ZONE = (-1.1, 1.1, 2.2, 3.7)


def _overlaps(rect: tuple[float, float, float, float],
              rects: list[tuple[float, float, float, float]], margin: float = 0.05) -> bool:
    x0, x1, y0, y1 = rect
    return any(x0 < b[1] + margin and b[0] - margin < x1 and y0 < b[3] + margin and
               b[2] - margin < y1 for b in rects)


def random_scene(rng: np.random.Generator, intrinsics: Intrinsics, *,
                 occluder_prob: float = 0.3,
                 person_zone: tuple[float, float, float, float] = PERSON_ZONE,
                 mount: tuple[tuple[float, float], tuple[float, float]] | None = None) -> Scene:
    """A random furnished room seen by a Kinect-like camera.

    The camera stands 0.85-1.35 m high, aimed at a point 1.0-1.1 m high 3 m away (pitch about
    -6 to +8 degrees), or, with `mount`, as high and pitched down as much as it says (a camera
    on a wall or a shelf above the heads, looking down), looking at a back wall
    3.7-5.5 m away (partly beyond the sensor's range, as in real rooms; further by as much as
    `person_zone` reaches beyond `PERSON_ZONE`); side walls are 1.7-3 m to either side (at
    least 0.6 m beside `person_zone`).
    Furniture (tables, cabinets, shelves, chairs, sofas, counters) stands along the walls
    outside `person_zone`; with probability `occluder_prob` a low object stands
    between the camera and that zone (1.2-1.65 m away), hiding a person's legs. Walls, floor and
    furniture are textured from real photographs; the light's direction, colour and strength
    vary.

    Parameters
    ----------
    rng : the random source (the scene is a deterministic function of its state).
    intrinsics : the camera the room is pre-rendered for.
    occluder_prob : probability of an occluding object in front of the person zone.
    person_zone : room-frame (x0, x1, y0, y1) metres kept free for the person.
    mount : ((lo, hi) height, metres; (lo, hi) pitch down, degrees), each drawn uniformly;
        None: the camera at a person's chest height described above.
    """
    mb = tex.MaterialBuilder()
    cam_h, room_to_cam = _random_camera(rng, mount)
    back = float(rng.uniform(3.7, 5.5)) + max(person_zone[3] - PERSON_ZONE[3], 0.0)
    # side walls at least 0.6 m beside a person zone wider than `PERSON_ZONE` (several people)
    xl = -max(float(rng.uniform(1.7, 3.0)), 0.6 - person_zone[0])
    xr = max(float(rng.uniform(1.7, 3.0)), person_zone[1] + 0.6)
    ceil = float(rng.uniform(2.5, 2.9))
    boxes = _room_shell(rng, mb, back, xl, xr, ceil)
    taken: list[tuple[float, float, float, float]] = []  # furniture footprints
    _wall_decor(rng, mb, back, xl, xr, boxes, taken)
    for _ in range(int(rng.integers(2, 6))):
        kind = str(rng.choice(['table', 'cabinet', 'shelf', 'chair', 'sofa', 'counter']))
        for _attempt in range(12):
            new = _furniture(rng, mb, kind, back, xl, xr)
            if new is None:
                break
            rect, parts = new
            if not _overlaps(rect, taken) and not _overlaps(rect, [person_zone], 0.0):
                taken.append(rect)
                boxes.extend(parts)
                break
    if rng.random() < occluder_prob:
        kind = str(rng.choice(['table', 'chair', 'cabinet', 'boxes']))
        x = float(rng.uniform(-0.45, 0.45))
        y = float(rng.uniform(1.2, 1.65))
        top = min(0.85, cam_h - 0.3) * float(rng.uniform(0.75, 1.0))
        boxes.extend(_occluder(rng, mb, kind, x, y, top))
    el = np.deg2rad(rng.uniform(25.0, 70.0))
    az = np.deg2rad(rng.uniform(-80.0, 80.0) + (180.0 if rng.random() < 0.15 else 0.0))
    light_room = np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
    warm = float(rng.uniform(-1.0, 1.0))
    colour = np.array([1.0 + 0.08 * warm, 1.0, 1.0 - 0.12 * warm])
    colour *= float(rng.uniform(0.85, 1.1))
    return _build_scene(intrinsics, cam_h, room_to_cam, tuple(boxes), mb.build(), light_room,
                        float(rng.uniform(0.3, 0.55)), float(rng.uniform(0.45, 0.75)), colour,
                        floor_index=0)


def _random_camera(rng: np.random.Generator,
                   mount: tuple[tuple[float, float], tuple[float, float]] | None = None
                   ) -> tuple[float, NDArray[np.float64]]:
    """The camera's height, metres, and its room-to-optical rotation (see `random_scene`)."""
    if mount is None:
        cam_h = float(rng.uniform(0.85, 1.35))
        # aimed at 1.0-1.1 m high, 3 m away: a whole person fits from about 2.5 m on, and
        # closer people lose their feet rather than their heads
        aim = float(rng.uniform(1.0, 1.1))
        pitch = np.arctan2(cam_h - aim, 3.0) + np.deg2rad(rng.uniform(-1.5, 1.5))
    else:
        cam_h = float(rng.uniform(*mount[0]))
        pitch = np.deg2rad(rng.uniform(*mount[1]))
    yaw = np.deg2rad(rng.uniform(-6.0, 6.0))
    roll = np.deg2rad(rng.normal(0.0, 0.8))
    return cam_h, camera_rotation(pitch, yaw, roll)


def _room_shell(rng: np.random.Generator, mb: tex.MaterialBuilder, back: float, xl: float,
                xr: float, ceil: float) -> list[Box]:
    """Floor, walls, ceiling and skirting of a room `back` metres deep between `xl` and `xr`;
    the floor first (`Scene.floor_index` 0)."""
    t = 0.05  # half thickness of walls
    tile, scale, name = tex.floor_tile(rng)
    m_floor = mb.add(f'floor/{name}', tile, scale)
    tile, scale, name = tex.wall_tile(rng)
    m_wall = mb.add(f'wall/{name}', tile, scale)
    m_accent = m_wall
    if rng.random() < 0.35:
        tile, scale, name = tex.wall_tile(rng)
        m_accent = mb.add(f'wall/{name}', tile, scale)
    m_ceiling = mb.add('ceiling', tex.tint(tex.grain(rng, 'moon'), (0.9, 0.9, 0.88), 0.02),
                       1.0)
    m_skirting = mb.add('skirting', *tex.furniture_tile(rng, 'laminate')[:2])
    cy = back / 2 - 0.5
    hy = back / 2 + 1.0
    return [
        Box((0.0, cy, -t), (8.0, hy, t), m_floor, kind='floor'),
        Box((0.0, back + t, ceil / 2), (8.0, t, ceil / 2 + 0.1), m_accent, kind='wall'),
        Box((xl - t, cy, ceil / 2), (t, hy, ceil / 2 + 0.1), m_wall, kind='wall'),
        Box((xr + t, cy, ceil / 2), (t, hy, ceil / 2 + 0.1), m_wall, kind='wall'),
        Box((0.0, cy, ceil + t), (8.0, hy, t), m_ceiling, kind='wall'),
        Box((0.0, back - 0.008, 0.045), ((xr - xl) / 2 + 0.1, 0.008, 0.045), m_skirting,
            kind='decor'),
        Box((xl + 0.008, cy, 0.045), (0.008, hy, 0.045), m_skirting, kind='decor'),
        Box((xr - 0.008, cy, 0.045), (0.008, hy, 0.045), m_skirting, kind='decor'),
    ]


def _wall_decor(rng: np.random.Generator, mb: tex.MaterialBuilder, back: float, xl: float,
                xr: float, boxes: list[Box], taken: list[tuple[float, float, float, float]]
                ) -> None:
    """A door (its footprint kept free in `taken`) and some pictures, added to `boxes`."""
    if rng.random() < 0.5:
        tile, scale, _ = tex.furniture_tile(rng, str(rng.choice(['wood', 'laminate'])))
        m_door = mb.add('door', tile, scale)
        x = float(rng.uniform(xl + 0.6, xr - 0.6))
        boxes.append(Box((x, back - 0.02, 1.02), (0.45, 0.02, 1.02), m_door, kind='decor'))
        taken.append((x - 0.5, x + 0.5, back - 0.9, back))  # keep the door free
    for _ in range(int(rng.integers(0, 4))):
        w = float(rng.uniform(0.3, 0.9))
        hgt = w * float(rng.uniform(0.6, 1.0))
        tile, _ = tex.picture_tile(rng, w / hgt)
        m_pic = mb.add('picture', tile, (w, hgt))  # the picture's face is exactly one tile
        z = float(rng.uniform(1.3, 1.8))
        if rng.random() < 0.6:
            x = float(rng.uniform(xl + w, xr - w))
            boxes.append(Box((x, back - 0.012, z), (w / 2, 0.012, hgt / 2), m_pic,
                             kind='decor'))
        else:
            side = xl if rng.random() < 0.5 else xr
            y = float(rng.uniform(2.0, back - 0.6))
            sign = 1.0 if side == xl else -1.0
            boxes.append(Box((side + sign * 0.012, y, z), (w / 2, 0.012, hgt / 2), m_pic,
                             yaw=float(sign * np.pi / 2), kind='decor'))


def table(center, half_top, height, mat, yaw=0.0, kind='furniture') -> list[Box]:
    """A table top on four legs (also chairs' seats)."""
    x, y = center
    hx, hy = half_top
    top = 0.02
    parts = [Box((x, y, height - top), (hx, hy, top), mat, yaw, kind)]
    leg = 0.025
    c, s = np.cos(yaw), np.sin(yaw)
    for sx in (-1, 1):
        for sy in (-1, 1):
            lx, ly = sx * (hx - leg), sy * (hy - leg)
            parts.append(Box((x + c * lx - s * ly, y + s * lx + c * ly, (height - 2 * top) / 2),
                             (leg, leg, (height - 2 * top) / 2), mat, yaw, kind))
    return parts


def _furniture(rng: np.random.Generator, mb: tex.MaterialBuilder, kind: str, back: float,
               xl: float, xr: float):
    """One piece of furniture against a wall: (footprint, boxes), or None if it cannot fit."""
    dims = {  # (width, depth, height) ranges
        'table': ((0.8, 1.6), (0.6, 0.9), (0.72, 0.78)),
        'cabinet': ((0.5, 1.2), (0.4, 0.6), (0.8, 1.9)),
        'shelf': ((0.6, 1.2), (0.3, 0.4), (1.2, 2.0)),
        'chair': ((0.42, 0.5), (0.42, 0.5), (0.44, 0.48)),
        'sofa': ((1.4, 2.1), (0.8, 0.95), (0.4, 0.45)),
        'counter': ((1.2, 2.4), (0.6, 0.65), (0.88, 0.92)),
    }[kind]
    w, d, h = (float(rng.uniform(*r)) for r in dims)
    wall = rng.choice(['back', 'left', 'right'])
    if wall == 'back':
        if xr - xl < w + 0.2:
            return None
        x = float(rng.uniform(xl + w / 2, xr - w / 2))
        y = back - d / 2 - 0.01
        yaw = 0.0
    else:
        lo, hi = 1.2, back - w / 2 - 0.05
        if hi <= lo:
            return None
        y = float(rng.uniform(lo, hi))
        x = xl + d / 2 + 0.01 if wall == 'left' else xr - d / 2 - 0.01
        yaw = float(np.pi / 2 if wall == 'left' else -np.pi / 2)
    ex, ey = (w / 2, d / 2) if yaw == 0.0 else (d / 2, w / 2)
    rect = (x - ex, x + ex, y - ey, y + ey)
    material = {'table': 'wood', 'cabinet': str(rng.choice(['wood', 'laminate'])),
                'shelf': 'wood', 'chair': str(rng.choice(['wood', 'metal'])), 'sofa': 'fabric',
                'counter': 'laminate'}[kind]
    tile, scale, name = tex.furniture_tile(rng, material)
    m = mb.add(f'{kind}/{name}', tile, scale)
    c, s = np.cos(yaw), np.sin(yaw)

    def at(lx: float, ly: float) -> tuple[float, float]:
        """Local (across, out of the wall) offsets -> room X, Y; local +y faces the room."""
        return x + c * lx + s * ly, y + s * lx - c * ly

    if kind == 'table':
        return rect, table((x, y), (w / 2, d / 2), h, m, yaw)
    if kind == 'chair':
        parts = table((x, y), (w / 2, d / 2), h, m, yaw)
        bx, by = at(0.0, -(d / 2 - 0.02))
        parts.append(Box((bx, by, h + 0.22), (w / 2, 0.02, 0.22), m, yaw))
        return rect, parts
    if kind == 'sofa':
        parts = [Box((x, y, h / 2), (w / 2, d / 2, h / 2), m, yaw)]
        bx, by = at(0.0, -(d / 2 - 0.1))
        parts.append(Box((bx, by, h + 0.22), (w / 2, 0.1, 0.22), m, yaw))
        for sx in (-1, 1):
            ax, ay = at(sx * (w / 2 - 0.09), 0.0)
            parts.append(Box((ax, ay, h + 0.1), (0.09, d / 2, 0.1), m, yaw))
        return rect, parts
    if kind == 'counter':
        tile2, scale2, _ = tex.furniture_tile(rng, 'wood')
        m2 = mb.add('counter/top', tile2, scale2)
        return rect, [Box((x, y, (h - 0.04) / 2), (w / 2, d / 2, (h - 0.04) / 2), m, yaw),
                      Box((x, y, h - 0.02), (w / 2 + 0.01, d / 2 + 0.02, 0.02), m2, yaw)]
    if kind == 'shelf':
        parts = [Box(at(0.0, -(d / 2 - 0.01)) + (h / 2,), (w / 2, 0.01, h / 2), m, yaw)]
        for sx in (-1, 1):
            parts.append(Box(at(sx * (w / 2 - 0.01), 0.0) + (h / 2,), (0.01, d / 2, h / 2), m,
                             yaw))
        n = int(rng.integers(3, 6))
        for k in range(n + 1):
            parts.append(Box((x, y, k * (h - 0.02) / n + 0.01), (w / 2, d / 2, 0.01), m, yaw))
        return rect, parts
    return rect, [Box((x, y, h / 2), (w / 2, d / 2, h / 2), m, yaw)]


def _occluder(rng: np.random.Generator, mb: tex.MaterialBuilder, kind: str, x: float,
              y: float, top: float) -> list[Box]:
    """A low object between the camera and the person zone (kind 'occluder'), at most `top`
    metres high (below the camera, or it would hide everything behind it)."""
    yaw = float(rng.uniform(-0.35, 0.35))
    if kind == 'table':
        tile, scale, _ = tex.furniture_tile(rng, 'wood')
        m = mb.add('occluder/table', tile, scale)
        return table((x, y), (float(rng.uniform(0.4, 0.7)), float(rng.uniform(0.3, 0.45))),
                      float(rng.uniform(0.8, 1.0)) * top, m, yaw, 'occluder')
    if kind == 'chair':
        tile, scale, _ = tex.furniture_tile(rng, str(rng.choice(['wood', 'metal'])))
        m = mb.add('occluder/chair', tile, scale)
        seat = min(0.46, 0.6 * top)
        back = top - seat
        parts = table((x, y), (0.23, 0.23), seat, m, yaw, 'occluder')
        c, s = np.cos(yaw), np.sin(yaw)
        parts.append(Box((x - s * 0.21, y + c * 0.21, seat + back / 2), (0.23, 0.02, back / 2),
                         m, yaw, 'occluder'))
        return parts
    if kind == 'cabinet':
        tile, scale, _ = tex.furniture_tile(rng, str(rng.choice(['wood', 'laminate'])))
        m = mb.add('occluder/cabinet', tile, scale)
        h = float(rng.uniform(0.6, 1.0)) * top
        return [Box((x, y, h / 2), (float(rng.uniform(0.3, 0.55)), 0.22, h / 2), m, yaw,
                    'occluder')]
    # a stack of cardboard boxes
    colour = tex.jitter_colour(rng, (0.62, 0.48, 0.32), 0.06)
    m = mb.add('occluder/boxes', tex.tint(tex.grain(rng, 'gravel', 0.3), colour, 0.06), 0.5)
    parts = []
    z = 0.0
    for _ in range(int(rng.integers(1, 3))):
        hx, hy, hz = (float(v) for v in rng.uniform([0.18, 0.15, 0.12], [0.32, 0.25, 0.25]))
        hz = min(hz, (top - z) / 2)
        if hz < 0.05:
            break
        parts.append(Box((x + float(rng.normal(0, 0.03)), y, z + hz), (hx, hy, hz), m,
                         yaw + float(rng.normal(0, 0.1)), 'occluder'))
        z += 2 * hz
    return parts


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------
