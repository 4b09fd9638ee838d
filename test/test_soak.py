"""A short soak (`make soak` is the long one: test/soak.py): the sample bag looped through the
graph into the recorder; no skeleton lost, a new track per loop, nothing exploding."""

from __future__ import annotations

from soak import soak

from pose4d_ros.graph.run import default_bag


def test_looping_bag_through_the_graph_loses_nothing(tmp_path):
    res = soak(default_bag(), 12.0, tmp_path)
    assert res['published'] > 0 and res['lost'] == 0, res
    assert res['received'] == res['published']
    loops = res['published'] / res['frames_per_loop']
    assert res['tracks']['distinct'] >= int(loops)  # stamps go back: a new track per loop
    assert res['tracks']['largest_coordinate'] < 1e4  # pixels and metres stay sane
