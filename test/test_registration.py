"""The depth image's registration to the colour image (`core.registration`) and `pose4d eval
--depth-shift`."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from pose4d_ros.cli.eval import depth_shift
from pose4d_ros.core.registration import edge_shift, shift_image


def _scene(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A colour image and its exactly registered depth: a few textured boxes (people,
    furniture) at 1.5-3 m before a wall at 4 m."""
    rng = np.random.default_rng(seed)
    color = np.full((240, 320, 3), 40, np.uint8)
    depth = np.full((240, 320), 4.0, np.float32)
    for _ in range(4):
        x0, y0 = rng.integers(10, 250), rng.integers(10, 150)
        w, h = rng.integers(25, 60), rng.integers(40, 80)
        color[y0:y0 + h, x0:x0 + w] = rng.integers(120, 255, 3)
        depth[y0:y0 + h, x0:x0 + w] = rng.uniform(1.5, 3.0)
    return color, depth


def test_shift_image_moves_an_image_and_fills_what_nothing_moved_into():
    depth = np.arange(12, dtype=np.float32).reshape(3, 4)
    moved = shift_image(depth, 1, -1)  # one right, one up
    assert_array_equal(moved[:2, 1:], depth[1:, :3])
    assert np.isnan(moved[:, 0]).all() and np.isnan(moved[2]).all()
    assert_array_equal(shift_image(depth.astype(np.uint16), -2, 0)[:, 2:], 0)
    assert np.isnan(shift_image(depth, 5, 0)).all()  # moved out whole
    assert_array_equal(shift_image(depth, 0, 0), depth)


def test_edge_shift_finds_how_far_the_depth_lies_beside_the_colour():
    frames = [_scene(seed) for seed in range(3)]
    registered = edge_shift(frames)  # to a pixel: a depth step's edge is two pixels wide
    assert abs(registered.dx) <= 1 and abs(registered.dy) <= 1 and registered.frames == 3
    assert registered.chamfer_px <= 1.0
    # depth registered 7 px to the left and 3 px below the colour: move it 7 right, 3 up
    off = [(c, shift_image(d, -7, 3)) for c, d in frames]
    found = edge_shift(off)
    assert abs(found.dx - 7) <= 1 and abs(found.dy + 3) <= 1, found
    assert found.chamfer_px < found.unshifted_px
    # and moved by it, the depth is registered again
    again = edge_shift((c, shift_image(d, found.dx, found.dy)) for c, d in off)
    assert abs(again.dx) <= 1 and abs(again.dy) <= 1, again


def test_edge_shift_needs_depth_edges_and_registered_sizes():
    color, depth = _scene(0)
    with pytest.raises(ValueError, match='no frame has depth edges'):
        edge_shift([(color, np.full_like(depth, 2.0))])
    with pytest.raises(ValueError, match=r'colour \(240, 320\) and depth \(120, 160\)'):
        edge_shift([(color, depth[::2, ::2])])


def test_depth_shift_flag_takes_two_whole_numbers_and_names_a_bad_value():
    assert depth_shift('10,2') == (10, 2) and depth_shift('-3,0') == (-3, 0)
    for bad in ('10', '1.5,2', 'a,b', '1,2,3'):
        with pytest.raises(argparse.ArgumentTypeError, match=repr(bad)):
            depth_shift(bad)
