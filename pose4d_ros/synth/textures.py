"""Texture tiles for the synthetic RGB-D renderer: real photographs and procedural fabrics.

Walls, floors and furniture are cut from the real photographs that scikit-image ships
(`skimage.data`: brick, gravel, grass, moon, astronaut, chelsea, coffee, rocket, ...), tinted
and tiled; clothes are procedural (plain with fabric grain, stripes, checks, denim) on top of the
same photographic grain. Every tile is a (T, T, 3) float32 albedo in [0, 1] (display values),
T = `TILE`. The renderer samples tiles bilinearly with mirrored repetition, so tiles need not be
seamless. A material is a tile plus its physical size (metres per tile along s and t) and the
probability that the Kinect's infrared pattern is lost on it (dark hair, black fabric).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

TILE = 128  # texels per tile side


@dataclass(frozen=True, eq=False)
class Materials:
    """A bank of materials in the arrays the numba kernels read.

    Attributes
    ----------
    tiles : (M, T, T, 3) float32 albedo in [0, 1].
    scale : (M, 2) float32 metres covered by one tile along the texture's s and t axes.
    ir_dropout : (M,) float32 probability of no depth reading on the material.
    names : M names, for debugging.
    """

    tiles: NDArray[np.float32]
    scale: NDArray[np.float32]
    ir_dropout: NDArray[np.float32]
    names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.names)


class MaterialBuilder:
    """Collects (name, tile, scale, dropout) entries and freezes them into `Materials`."""

    def __init__(self) -> None:
        self._entries: list[tuple[str, NDArray[np.float32], tuple[float, float], float]] = []

    def add(self, name: str, tile: NDArray[np.float32], scale: float | tuple[float, float],
            ir_dropout: float = 0.0) -> int:
        if np.isscalar(scale):
            scale = (float(scale), float(scale))  # type: ignore[arg-type]
        tile = np.asarray(tile, dtype=np.float32)
        if tile.shape != (TILE, TILE, 3):
            tile = cv2.resize(tile, (TILE, TILE), interpolation=cv2.INTER_AREA)
        self._entries.append((name, np.clip(tile, 0.0, 1.0), scale, float(ir_dropout)))
        return len(self._entries) - 1

    def build(self) -> Materials:
        if not self._entries:
            raise ValueError('no materials')
        return Materials(
            tiles=np.stack([e[1] for e in self._entries]).astype(np.float32),
            scale=np.array([e[2] for e in self._entries], dtype=np.float32),
            ir_dropout=np.array([e[3] for e in self._entries], dtype=np.float32),
            names=tuple(e[0] for e in self._entries),
        )


# --------------------------------------------------------------------------------------------
# The photographs
# --------------------------------------------------------------------------------------------

_GREY_PHOTOS = ('brick', 'gravel', 'grass', 'moon', 'camera', 'coins')
_COLOUR_PHOTOS = ('astronaut', 'chelsea', 'coffee', 'rocket', 'hubble_deep_field',
                  'immunohistochemistry', 'cat', 'retina')
PICTURES = ('astronaut', 'chelsea', 'coffee', 'rocket', 'hubble_deep_field', 'cat', 'camera',
            'moon')


@functools.cache
def photo(name: str) -> NDArray[np.float32]:
    """A scikit-image sample photograph as float32 in [0, 1]: (H, W) grey or (H, W, 3) colour."""
    import skimage.data

    if name not in _GREY_PHOTOS + _COLOUR_PHOTOS:
        raise ValueError(f'unknown photograph {name!r}')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        img = getattr(skimage.data, name)()
    img = np.asarray(img, dtype=np.float32) / 255.0
    if img.ndim == 3:
        img = img[:, :, :3]
        # retina is mostly black border: keep its centre
        if name == 'retina':
            h, w = img.shape[:2]
            img = img[h // 4: 3 * h // 4, w // 4: 3 * w // 4]
    return img


def _crop(img: NDArray[np.float32], rng: np.random.Generator, frac: float,
          aspect: float = 1.0) -> NDArray[np.float32]:
    """A random crop covering `frac` of the shorter side, with width/height = `aspect`."""
    h, w = img.shape[:2]
    ch = max(8, int(min(h, w / aspect) * frac))
    cw = max(8, int(ch * aspect))
    y0 = int(rng.integers(0, h - ch + 1))
    x0 = int(rng.integers(0, w - cw + 1))
    return img[y0:y0 + ch, x0:x0 + cw]


def grain(rng: np.random.Generator, source: str = 'gravel', frac: float = 0.5,
          stretch: float = 1.0) -> NDArray[np.float32]:
    """Zero-mean, unit-std photographic grain (T, T) from a grey photograph.

    `stretch` > 1 elongates the grain along s (wood fibres, brushed metal).
    """
    img = photo(source)
    if img.ndim == 3:
        img = img.mean(axis=2)
    patch = _crop(img, rng, frac / max(stretch, 1.0) if stretch > 1 else frac)
    if stretch > 1:
        patch = cv2.resize(patch, (int(patch.shape[1] * stretch), patch.shape[0]))
        patch = patch[:, :patch.shape[0]]
    tile = cv2.resize(patch, (TILE, TILE), interpolation=cv2.INTER_AREA)
    tile = tile - cv2.GaussianBlur(tile, (0, 0), TILE / 8)  # keep the fine structure only
    tile = tile / (tile.std() + 1e-6)
    # clip the heavy tails (craters of the moon, stones of the gravel) to a fabric-like grain
    return np.clip(tile, -2.0, 2.0).astype(np.float32)


def tint(grey: NDArray[np.float32], colour: NDArray[np.floating] | tuple[float, ...],
         contrast: float) -> NDArray[np.float32]:
    """Colour a zero-mean grain: `colour * (1 + contrast * grain)`, (T, T, 3)."""
    colour = np.asarray(colour, dtype=np.float32)
    return (colour[None, None, :] * (1.0 + contrast * grey[:, :, None])).astype(np.float32)


def photo_tile(name: str, rng: np.random.Generator, frac: float = 1.0,
               aspect: float = 1.0) -> NDArray[np.float32]:
    """A crop of a photograph resized to one tile, (T, T, 3) (grey photos become grey RGB)."""
    img = photo(name)
    patch = _crop(img, rng, frac, aspect)
    if patch.ndim == 2:
        patch = np.repeat(patch[:, :, None], 3, axis=2)
    return cv2.resize(patch, (TILE, TILE), interpolation=cv2.INTER_AREA).astype(np.float32)


def jitter_colour(rng: np.random.Generator, colour: tuple[float, float, float],
                  amount: float = 0.08) -> NDArray[np.float32]:
    c = np.asarray(colour, dtype=np.float32) * (1.0 + rng.normal(0.0, amount, 3))
    return np.clip(c, 0.02, 0.98).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Room materials
# --------------------------------------------------------------------------------------------

WALL_PAINTS = ((0.86, 0.84, 0.78), (0.80, 0.82, 0.80), (0.90, 0.88, 0.84), (0.72, 0.76, 0.80),
               (0.82, 0.74, 0.62), (0.70, 0.78, 0.70), (0.92, 0.92, 0.90), (0.78, 0.70, 0.72))
WOODS = ((0.55, 0.36, 0.20), (0.68, 0.50, 0.32), (0.40, 0.26, 0.15), (0.78, 0.64, 0.45),
         (0.30, 0.20, 0.13))
LAMINATES = ((0.90, 0.90, 0.88), (0.25, 0.25, 0.27), (0.62, 0.64, 0.66), (0.82, 0.78, 0.70))
FABRICS = ((0.35, 0.38, 0.45), (0.55, 0.30, 0.25), (0.45, 0.45, 0.42), (0.25, 0.32, 0.28),
           (0.60, 0.55, 0.48))


def wall_tile(rng: np.random.Generator) -> tuple[NDArray[np.float32], float, str]:
    """A wall: painted plaster, brick, or striped wallpaper. Returns (tile, metres, name)."""
    kind = rng.choice(['paint', 'paint', 'paint', 'brick', 'wallpaper'])
    if kind == 'brick':
        painted = rng.random() < 0.4
        colour = jitter_colour(rng, (0.85, 0.83, 0.80) if painted else (0.62, 0.36, 0.26))
        img = photo('brick')
        patch = _crop(img, rng, 1.0)
        g = cv2.resize(patch, (TILE, TILE), interpolation=cv2.INTER_AREA)
        g = (g - g.mean()) / (g.std() + 1e-6)
        return tint(g, colour, 0.18 if painted else 0.3), float(rng.uniform(1.0, 1.6)), 'brick'
    colour = jitter_colour(rng, WALL_PAINTS[rng.integers(len(WALL_PAINTS))], 0.05)
    g = grain(rng, 'moon', 0.6)
    if kind == 'paint':
        return tint(g, colour, 0.025), float(rng.uniform(0.8, 1.5)), 'paint'
    period = int(rng.choice([8, 12, 16, 32]))
    s = np.arange(TILE)
    stripe = ((s // (period // 2)) % 2).astype(np.float32)[None, :, None]
    other = colour * np.float32(rng.uniform(0.8, 0.93))
    tile = colour[None, None, :] * (1 - stripe) + other[None, None, :] * stripe
    tile = np.broadcast_to(tile, (TILE, TILE, 3)) * (1.0 + 0.02 * g[:, :, None])
    return tile.astype(np.float32), float(rng.uniform(0.8, 1.4)), 'wallpaper'


def floor_tile(rng: np.random.Generator) -> tuple[NDArray[np.float32], float, str]:
    """A floor: wooden planks, ceramic tiles, carpet or concrete."""
    kind = rng.choice(['planks', 'planks', 'tiles', 'carpet', 'concrete'])
    if kind == 'planks':
        return wood_tile(rng, planks=int(rng.integers(6, 10))), float(rng.uniform(1.0, 1.5)), \
            'planks'
    if kind == 'tiles':
        n = int(rng.choice([2, 3, 4]))
        colour = jitter_colour(rng, [(0.85, 0.84, 0.80), (0.55, 0.52, 0.50), (0.75, 0.68, 0.58),
                                     (0.35, 0.35, 0.36)][rng.integers(4)], 0.05)
        g = grain(rng, 'gravel', 0.3)
        tile = tint(g, colour, 0.05)
        cell = np.arange(TILE) * n // TILE  # which ceramic tile each texel row/column is in
        per_tile = 1.0 + rng.normal(0, 0.03, (n, n)).astype(np.float32)
        tile *= per_tile[cell[:, None], cell[None, :]][:, :, None]
        edge = np.r_[True, np.diff(cell) > 0]
        edge |= np.r_[edge[1:], False]  # grout lines 2 texels wide
        grout = edge[:, None] | edge[None, :]
        tile[grout] = colour * 0.6
        return tile, float(n * rng.uniform(0.3, 0.5)), 'tiles'
    if kind == 'carpet':
        colour = jitter_colour(rng, FABRICS[rng.integers(len(FABRICS))], 0.1)
        return tint(grain(rng, 'gravel', 0.25), colour, 0.12), float(rng.uniform(0.4, 0.8)), \
            'carpet'
    colour = jitter_colour(rng, (0.55, 0.55, 0.53), 0.06)
    g = cv2.GaussianBlur(grain(rng, 'gravel', 0.6), (0, 0), 1.0)
    return tint(g / (g.std() + 1e-6), colour, 0.06), float(rng.uniform(0.8, 1.5)), 'concrete'


def wood_tile(rng: np.random.Generator, planks: int = 1) -> NDArray[np.float32]:
    """Wood grain (fibres along s), optionally cut into `planks` boards with dark seams."""
    colour = jitter_colour(rng, WOODS[rng.integers(len(WOODS))], 0.06)
    g = grain(rng, 'grass', 0.6, stretch=8.0)
    tile = tint(g, colour, 0.12)
    if planks > 1:
        edges = np.linspace(0, TILE, planks + 1).astype(int)
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            tile[a:b] *= np.float32(1.0 + rng.normal(0, 0.08))
            tile[a:a + 1] *= 0.55
    return tile


def furniture_tile(rng: np.random.Generator, kind: str) -> tuple[NDArray[np.float32], float,
                                                                 str]:
    """A furniture surface: 'wood', 'laminate', 'fabric' or 'metal'."""
    if kind == 'wood':
        return wood_tile(rng), float(rng.uniform(0.6, 1.2)), 'wood'
    if kind == 'laminate':
        colour = jitter_colour(rng, LAMINATES[rng.integers(len(LAMINATES))], 0.04)
        return tint(grain(rng, 'moon', 0.5), colour, 0.02), 1.0, 'laminate'
    if kind == 'fabric':
        colour = jitter_colour(rng, FABRICS[rng.integers(len(FABRICS))], 0.12)
        return tint(grain(rng, 'gravel', 0.2), colour, 0.1), float(rng.uniform(0.3, 0.6)), \
            'fabric'
    colour = jitter_colour(rng, (0.2, 0.2, 0.22), 0.1)
    return tint(grain(rng, 'grass', 0.5, stretch=6.0), colour, 0.05), 0.5, 'metal'


def picture_tile(rng: np.random.Generator, aspect: float) -> tuple[NDArray[np.float32], str]:
    """A framed photograph for a wall (a crop of width/height `aspect`)."""
    name = str(rng.choice(PICTURES))
    tile = photo_tile(name, rng, float(rng.uniform(0.7, 1.0)), aspect)
    # a thin frame
    frame = jitter_colour(rng, [(0.1, 0.1, 0.1), (0.9, 0.9, 0.88), (0.5, 0.35, 0.2)][
        rng.integers(3)], 0.05)
    b = 4
    tile[:b], tile[-b:], tile[:, :b], tile[:, -b:] = frame, frame, frame, frame
    return tile, name


# --------------------------------------------------------------------------------------------
# Body materials
# --------------------------------------------------------------------------------------------

SKIN_TONES = ((0.93, 0.76, 0.65), (0.87, 0.67, 0.53), (0.78, 0.57, 0.42), (0.64, 0.45, 0.32),
              (0.48, 0.32, 0.22), (0.34, 0.22, 0.15))
HAIR_COLOURS = ((0.06, 0.05, 0.05), (0.18, 0.11, 0.07), (0.33, 0.21, 0.12), (0.62, 0.48, 0.30),
                (0.55, 0.55, 0.55), (0.45, 0.20, 0.10))
SHIRT_COLOURS = ((0.92, 0.92, 0.90), (0.12, 0.12, 0.13), (0.45, 0.47, 0.50), (0.12, 0.17, 0.35),
                 (0.65, 0.12, 0.12), (0.15, 0.40, 0.22), (0.25, 0.45, 0.70), (0.85, 0.72, 0.20),
                 (0.70, 0.62, 0.50), (0.50, 0.20, 0.45), (0.90, 0.45, 0.15), (0.60, 0.75, 0.85))
TROUSER_COLOURS = ((0.16, 0.24, 0.42), (0.25, 0.33, 0.50), (0.08, 0.08, 0.09), (0.60, 0.52, 0.38),
                   (0.35, 0.35, 0.37), (0.30, 0.22, 0.15), (0.20, 0.28, 0.22))
SHOE_COLOURS = ((0.06, 0.06, 0.06), (0.88, 0.88, 0.86), (0.30, 0.18, 0.10), (0.35, 0.35, 0.40))


def skin_tile(rng: np.random.Generator) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Skin albedo tile and its base colour."""
    base = np.asarray(SKIN_TONES[rng.integers(len(SKIN_TONES))], dtype=np.float32)
    colour = jitter_colour(rng, tuple(base), 0.04)
    return tint(grain(rng, 'moon', 0.3), colour, 0.03), colour


def face_tile(rng: np.random.Generator, skin: NDArray[np.float32], hair: NDArray[np.float32]
              ) -> NDArray[np.float32]:
    """The head's skin tile with eyebrows, eyes and a mouth on the front.

    The head ellipsoid maps its surface onto one tile (s around the vertical axis, the face at
    s = half a turn, i.e. the tile's middle column; t from the crown down), so the features are
    drawn at fixed places: eyes at 45 % of the height, mouth at 70 %.
    """
    tile = skin.copy()
    n = TILE
    skin_c = tile.reshape(-1, 3).mean(axis=0)
    c = n // 2
    sep = max(2, int(round(n * rng.uniform(0.055, 0.07))))
    eye_row = int(n * rng.uniform(0.44, 0.47))
    brow = (0.5 * skin_c + 0.5 * hair.reshape(-1, 3).mean(axis=0) * 0.6).astype(np.float32)
    for sx in (-1, 1):
        cv2.ellipse(tile, (c + sx * sep, eye_row), (3, 1), 0, 0, 360,
                    tuple(float(v) for v in skin_c * 0.35), -1)
        cv2.line(tile, (c + sx * sep - 3, eye_row - 4), (c + sx * sep + 3, eye_row - 4),
                 tuple(float(v) for v in brow), 1)
    mouth = skin_c * np.array([0.75, 0.5, 0.5], np.float32)
    mouth_row = int(n * rng.uniform(0.68, 0.72))
    cv2.line(tile, (c - 4, mouth_row), (c + 4, mouth_row), tuple(float(v) for v in mouth), 1)
    # nose shading
    cv2.line(tile, (c, eye_row + 3), (c, mouth_row - 5), tuple(float(v) for v in skin_c * 0.85),
             1)
    return cv2.GaussianBlur(tile, (0, 0), 0.6)


def hair_tile(rng: np.random.Generator) -> tuple[NDArray[np.float32], float]:
    """Hair albedo tile (strands along t) and its infrared dropout (dark hair absorbs)."""
    colour = jitter_colour(rng, HAIR_COLOURS[rng.integers(len(HAIR_COLOURS))], 0.08)
    g = grain(rng, 'grass', 0.5, stretch=6.0).T
    dropout = float(np.clip(0.35 - colour.mean(), 0.0, 0.3))
    return tint(np.ascontiguousarray(g), colour, 0.25), dropout


def cloth_tile(rng: np.random.Generator, palette: tuple[tuple[float, float, float], ...],
               kinds: tuple[str, ...] = ('plain', 'plain', 'plain', 'stripes', 'checks', 'print')
               ) -> tuple[NDArray[np.float32], float, float]:
    """A garment of one of `kinds` ('plain', 'stripes', 'checks', 'print', 'denim').

    Returns (tile, metres per tile, infrared dropout).
    """
    colour = jitter_colour(rng, palette[rng.integers(len(palette))], 0.07)
    g = grain(rng, 'gravel', 0.15)
    kind = str(rng.choice(list(kinds)))
    scale = float(rng.uniform(0.25, 0.45))
    if kind == 'denim':
        twill = grain(rng, 'grass', 0.3, stretch=4.0)
        twill = cv2.warpAffine(twill, np.float32([[1, 0.5, 0], [0, 1, 0]]), (TILE, TILE),
                               borderMode=cv2.BORDER_REFLECT)
        tile = tint(0.5 * g + 0.8 * twill, colour, 0.08)
    elif kind == 'plain':
        tile = tint(g, colour, 0.06)
    elif kind == 'print':
        # a large photographic pattern (camouflage-like), muted towards the base colour
        pat = photo_tile(str(rng.choice(['hubble_deep_field', 'immunohistochemistry', 'coffee',
                                         'retina'])), rng, float(rng.uniform(0.2, 0.5)))
        tile = (0.55 * pat + 0.45 * colour[None, None, :]).astype(np.float32)
        tile *= (1.0 + 0.05 * g[:, :, None])
        scale = float(rng.uniform(0.3, 0.6))
    else:
        other = jitter_colour(rng, palette[rng.integers(len(palette))], 0.07)
        n = int(rng.choice([4, 6, 8, 12]))
        band = ((np.arange(TILE) * n // TILE) % 2).astype(np.float32)
        rows = band[:, None] * np.ones(TILE, np.float32)[None, :]
        if kind == 'stripes':
            mix = rows  # horizontal stripes (t runs around/along the body)
        else:
            mix = 0.5 * (rows + rows.T)
        tile = colour[None, None, :] * (1 - mix[:, :, None]) + other[None, None, :] * \
            mix[:, :, None]
        tile = (tile * (1.0 + 0.06 * g[:, :, None])).astype(np.float32)
    dropout = float(np.clip(0.12 - colour.mean(), 0.0, 0.1))
    return tile, scale, dropout
