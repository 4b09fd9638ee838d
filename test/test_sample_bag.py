"""The bundled sample bags are what `make sample-bag` makes, and they read back completely."""

from __future__ import annotations

import re
import subprocess

import pytest
from conftest import REPO
from harness import executable

from pose4d_ros.datasets import bag, cad60_bag

SAMPLE = REPO / 'bags' / 'sample'
PEOPLE2 = REPO / 'bags' / 'sample_people2'


def _size(path):
    return sum(f.stat().st_size for f in path.iterdir())


def test_sample_bag_content():
    info = bag.topics(SAMPLE)
    counts = {t: i.count for t, i in info.items()}
    assert counts == {cad60_bag.COLOR_TOPIC: 45, cad60_bag.DEPTH_TOPIC: 45,
                      cad60_bag.INFO_TOPIC: 45, cad60_bag.SKELETON_TOPIC: 45,
                      cad60_bag.MASK_TOPIC: 45}
    assert _size(SAMPLE) < 10.5e6, f'the sample bag has grown to {_size(SAMPLE) / 1e6:.1f} MB'
    for m in bag.read_messages(SAMPLE, [cad60_bag.SKELETON_TOPIC]):
        gt = bag.deserialize(m)
        assert len(gt.joints) == 15


def test_two_person_sample_bag_content():
    counts = {t: i.count for t, i in bag.topics(PEOPLE2).items()}
    assert counts == dict.fromkeys(
        (cad60_bag.COLOR_TOPIC, cad60_bag.DEPTH_TOPIC, cad60_bag.INFO_TOPIC,
         cad60_bag.SKELETON_TOPIC, cad60_bag.SKELETONS_TOPIC, cad60_bag.MASK_TOPIC), 50)
    assert _size(PEOPLE2) < 12e6, f'the two-person bag has grown to {_size(PEOPLE2) / 1e6:.1f} MB'
    seen = {1: 0, 2: 0}
    for m in bag.read_messages(PEOPLE2, [cad60_bag.SKELETONS_TOPIC]):
        people = bag.deserialize(m).skeletons
        assert sorted(p.track_id for p in people) == [1, 2]
        for p in people:
            assert len(p.joints) == 15
            seen[p.track_id] += any(j.confidence > 0 for j in p.joints)
    assert seen == {1: 50, 2: 50}  # both people in view in every frame


def _recipe() -> str:
    text = (REPO / 'Makefile').read_text().split('\nsample-bag:')[1].split('\n\n')[0]
    return text.replace('\\\n', ' ')


@pytest.mark.slow
@pytest.mark.parametrize('bundled', [SAMPLE, PEOPLE2], ids=lambda p: p.name)
def test_make_sample_bag_commands_reproduce_it(tmp_path, shared_data, bundled):
    """Run the Makefile's recipe (synth + cad60-to-bag) for the bag and compare every
    message."""
    recipe = _recipe()
    convert = re.search(rf'pose4d cad60-to-bag (\S+) build/sample_bag/{bundled.name}(.*)',
                        recipe)
    source, options = convert.group(1), convert.group(2).split()
    synth = re.search(rf'pose4d synth (.*?--out {source} .*?) --quiet', recipe)
    args = synth.group(1).split()
    args[args.index('$(UTKINECT)')] = str(shared_data / 'utkinect')
    args[args.index(source)] = str(tmp_path / 'cad60')
    pose4d = str(executable('pose4d'))
    subprocess.run([pose4d, 'synth', *args, '--quiet'], check=True, timeout=300)
    subprocess.run([pose4d, 'cad60-to-bag', str(tmp_path / 'cad60'), str(tmp_path / 'bag'),
                    *options], check=True, capture_output=True, timeout=300)
    made = [(m.topic, m.timestamp_ns, m.data) for m in bag.read_messages(tmp_path / 'bag')]
    kept = [(m.topic, m.timestamp_ns, m.data) for m in bag.read_messages(bundled)]
    assert len(made) == len(kept)
    assert made == kept
