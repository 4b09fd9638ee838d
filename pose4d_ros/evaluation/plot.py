"""Accuracy curves for `pose4d eval --plot`, drawn with OpenCV (no plotting library needed).

One panel per joint group (PCK against the threshold alpha, 0 to 0.5, one curve per row: the
same rule as the table, `core.metrics.curves`), one for the average over the groups, and one
for the 3-D errors: the percentage of joints within d millimetres of the ground truth against
d, over every joint a row places in 3-D (the `within_10cm` of the table is its value at 100).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.skeleton import JOINT_GROUPS

ALPHAS = np.round(np.linspace(0.0, 0.5, 51), 3)  # the PCK thresholds of the curves
DISTANCES_MM = np.linspace(0.0, 300.0, 61)  # the 3-D distances of the error panel

# BGR, one per row, in the order the rows come (the table's order)
COLOURS = ((200, 90, 30), (40, 150, 40), (30, 30, 210), (160, 60, 160), (0, 140, 220),
           (120, 120, 120), (200, 170, 0))
PANEL = (330, 240)  # width, height of a panel, pixels
MARGIN = (46, 28, 14, 34)  # left, top, right, bottom inside a panel
FONT = cv2.FONT_HERSHEY_SIMPLEX


def within(distances_mm: NDArray[np.floating], d_mm: NDArray[np.floating]) -> NDArray:
    """Percentage of `distances_mm` at most each of `d_mm` (0 where there are none)."""
    dist = np.sort(np.asarray(distances_mm, np.float64))
    if dist.size == 0:
        return np.zeros(len(d_mm))
    return 100.0 * np.searchsorted(dist, d_mm, side='right') / dist.size


def draw(curves: dict[str, dict], title: str) -> NDArray[np.uint8]:
    """The figure: `curves` is {row name: `core.metrics.curves` at `ALPHAS`}; BGR uint8."""
    groups = [g for g in JOINT_GROUPS if any(g in c['pck'] for c in curves.values())]
    panels = [(g, {n: c['pck'][g] for n, c in curves.items() if g in c['pck']}) for g in groups]
    key = 'average7' if all(np.isfinite(c['pck'].get('average7', [np.nan])[-1])
                            for c in curves.values()) else 'average'
    panels.append((f'{key} (groups)', {n: c['pck'][key] for n, c in curves.items()}))
    with_3d = {n: np.concatenate([np.asarray(d, np.float64) for d in c['distance_mm'].values()])
               for n, c in curves.items() if 'distance_mm' in c}
    cols = 3
    rows = -(-(len(panels) + bool(with_3d)) // cols)
    legend_h = 30 + 22 * ((len(curves) + 2) // 3)
    w, h = PANEL
    img = np.full((legend_h + rows * h, cols * w, 3), 255, np.uint8)
    cv2.putText(img, title, (10, 22), FONT, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    colour = {n: COLOURS[i % len(COLOURS)] for i, n in enumerate(curves)}
    for i, name in enumerate(curves):
        x, y = 10 + (i % 3) * w, 44 + 22 * (i // 3)
        cv2.line(img, (x, y - 5), (x + 24, y - 5), colour[name], 3, cv2.LINE_AA)
        cv2.putText(img, name, (x + 32, y), FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for k, (name, lines) in enumerate(panels):
        origin = (k % cols * w, legend_h + k // cols * h)
        _panel(img, origin, f'PCK@alpha: {name}', ALPHAS, lines, colour, x_max=0.5,
               x_ticks=(0.0, 0.1, 0.2, 0.3, 0.4, 0.5), x_fmt='{:g}')
    if with_3d:
        k = len(panels)
        origin = (k % cols * w, legend_h + k // cols * h)
        lines = {n: within(d, DISTANCES_MM) for n, d in with_3d.items()}
        _panel(img, origin, '3-D: joints within d mm (%)', DISTANCES_MM, lines, colour,
               x_max=300.0, x_ticks=(0, 100, 200, 300), x_fmt='{:g}')
    return img


def _panel(img: NDArray[np.uint8], origin: tuple[int, int], title: str, xs: NDArray,
           lines: dict[str, list[float] | NDArray], colour: dict[str, tuple[int, int, int]], *,
           x_max: float, x_ticks: tuple[float, ...], x_fmt: str) -> None:
    """One panel: axes 0..x_max and 0..100 %, grid, ticks, a polyline per row."""
    ox, oy = origin
    left, top, right, bottom = MARGIN
    x0, y0 = ox + left, oy + top
    x1, y1 = ox + PANEL[0] - right, oy + PANEL[1] - bottom

    def to_px(x: NDArray, y: NDArray) -> NDArray[np.int32]:
        px = x0 + (np.asarray(x, np.float64) / x_max) * (x1 - x0)
        py = y1 - (np.clip(np.asarray(y, np.float64), 0.0, 100.0) / 100.0) * (y1 - y0)
        return np.rint(np.stack([px, py], axis=1) * 16).astype(np.int32)

    cv2.putText(img, title, (x0, oy + 18), FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for v in (0, 25, 50, 75, 100):
        y = int(round(y1 - v / 100.0 * (y1 - y0)))
        cv2.line(img, (x0, y), (x1, y), (225, 225, 225), 1)
        cv2.putText(img, str(v), (ox + 14, y + 4), FONT, 0.35, (60, 60, 60), 1, cv2.LINE_AA)
    for t in x_ticks:
        x = int(round(x0 + t / x_max * (x1 - x0)))
        cv2.line(img, (x, y0), (x, y1), (225, 225, 225), 1)
        cv2.putText(img, x_fmt.format(t), (x - 8, y1 + 16), FONT, 0.35, (60, 60, 60), 1,
                    cv2.LINE_AA)
    cv2.rectangle(img, (x0, y0), (x1, y1), (0, 0, 0), 1)
    for name, ys in lines.items():
        ys = np.asarray(ys, np.float64)
        ok = np.isfinite(ys)
        if ok.sum() >= 2:
            cv2.polylines(img, [to_px(xs[ok], ys[ok])], False, colour[name], 2, cv2.LINE_AA,
                          shift=4)
