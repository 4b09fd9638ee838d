"""The bundled sample bag is what `make sample-bag` makes, and it reads back completely."""

from __future__ import annotations

import re
import subprocess

import pytest
from conftest import REPO
from harness import executable

from pose4d_ros.datasets import bag, cad60_bag

SAMPLE = REPO / 'bags' / 'sample'


def test_sample_bag_content():
    info = bag.topics(SAMPLE)
    counts = {t: i.count for t, i in info.items()}
    assert counts == {cad60_bag.COLOR_TOPIC: 45, cad60_bag.DEPTH_TOPIC: 45,
                      cad60_bag.INFO_TOPIC: 45, cad60_bag.SKELETON_TOPIC: 45,
                      cad60_bag.MASK_TOPIC: 45}
    size = sum(f.stat().st_size for f in SAMPLE.iterdir())
    assert size < 10.5e6, f'the sample bag has grown to {size / 1e6:.1f} MB'
    for m in bag.read_messages(SAMPLE, [cad60_bag.SKELETON_TOPIC]):
        gt = bag.deserialize(m)
        assert len(gt.joints) == 15


@pytest.mark.slow
def test_make_sample_bag_commands_reproduce_it(tmp_path, shared_data):
    """Run the Makefile's recipe (synth + cad60-to-bag) and compare every message."""
    recipe = (REPO / 'Makefile').read_text().split('\nsample-bag:')[1].split('\n\n')[0]
    synth = re.search(r'pose4d synth (.*?) --quiet', recipe.replace('\\\n', ' '), re.S)
    args = synth.group(1).split()
    args[args.index('$(UTKINECT)')] = str(shared_data / 'utkinect')
    args[args.index('build/sample_cad60')] = str(tmp_path / 'cad60')
    pose4d = str(executable('pose4d'))
    subprocess.run([pose4d, 'synth', *args, '--quiet'], check=True, timeout=300)
    subprocess.run([pose4d, 'cad60-to-bag', str(tmp_path / 'cad60'), str(tmp_path / 'bag')],
                   check=True, capture_output=True, timeout=300)
    made = [(m.topic, m.timestamp_ns, m.data) for m in bag.read_messages(tmp_path / 'bag')]
    bundled = [(m.topic, m.timestamp_ns, m.data) for m in bag.read_messages(SAMPLE)]
    assert len(made) == len(bundled)
    assert made == bundled
