"""Damaged files wherever we read them: one clear error naming the file, a non-zero exit, no
traceback (unless `pose4d --debug`), nothing half-written under the output's name.

Bags (mcap with zstd chunks, sqlite3) are truncated at several offsets and have bytes flipped
at seeded positions; a reader either reads what is intact or raises ValueError naming the bag,
never another exception. The CLI and the replay node are run as a user runs them.
"""

from __future__ import annotations

import random
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from harness import executable

from pose4d_ros.core.dpm.model import load_model
from pose4d_ros.datasets import bag
from pose4d_ros.graph.run import default_bag
from pose4d_ros.models import model_path

SAMPLE = default_bag()


def copy_bag(dst: Path, storage: str) -> Path:
    """The sample bag's first 60 messages in `storage` format."""
    with bag.BagWriter(dst, storage=storage) as writer:
        for k, m in enumerate(bag.read_messages(SAMPLE)):
            if k == 60:
                break
            if m.topic not in writer.counts:
                writer.add_topic(m.topic, m.msgtype)
            writer.write(m.topic, m.timestamp_ns, m.data)
    return dst


def storage_file(path: Path) -> Path:
    return next(p for p in path.iterdir() if p.suffix in ('.mcap', '.db3'))


def truncate(path: Path, fraction: float) -> None:
    f = storage_file(path)
    f.write_bytes(f.read_bytes()[:int(f.stat().st_size * fraction)])


def flip(path: Path, seed: int, n: int = 20) -> None:
    f = storage_file(path)
    data = bytearray(f.read_bytes())
    rng = random.Random(seed)
    for _ in range(n):
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    f.write_bytes(bytes(data))


def read_everything(path: Path) -> int:
    n = 0
    for m in bag.read_messages(path):
        bag.deserialize(m)
        n += 1
    return n


# A damaged bag's error, in our words: what is wrong and where (never a library's message)
CLEAR = re.compile(r': (empty file \(0 bytes\)|not an (MCAP file|SQLite database)|truncated after '
                   r'\d+ bytes|damaged (header|data section|chunk|summary|footer) at offset \d+ '
                   r'|damaged SQLite database|damaged \(|.* is not a valid )')


def flip_header(path: Path) -> None:
    """8 bytes flipped in the first record (MCAP: the header's length field)."""
    f = storage_file(path)
    data = bytearray(f.read_bytes())
    data[9:17] = bytes(b ^ 0xFF for b in data[9:17])
    f.write_bytes(bytes(data))


def magic_only(path: Path) -> None:
    f = storage_file(path)
    f.write_bytes(f.read_bytes()[:8])


def read_all(path: Path) -> list[bytes]:
    out = []
    for m in bag.read_messages(path):
        bag.deserialize(m)
        out.append(m.data)
    return out


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_damaged_bags_read_what_is_intact_or_name_the_bag(tmp_path, storage):
    """Each damage either reads exactly the intact bag's messages or fails with one line that
    names the file and says what is wrong. (SQLite keeps no checksums: bytes flipped inside a
    message's data read as that message, changed; an MCAP chunk's compressed data do not.)"""
    intact = copy_bag(tmp_path / 'intact', storage)
    expected = read_all(intact)
    assert len(expected) == 60
    damages = [('truncate', f) for f in (0.0, 0.1, 0.5, 0.9, 0.99)]
    damages += [('flip', seed) for seed in range(12)] + [('magic_only', 0), ('header', 0)]
    outcomes = {}
    for kind, arg in damages:
        damaged = tmp_path / f'{kind}_{arg}'
        shutil.copytree(intact, damaged)
        if kind == 'truncate':
            truncate(damaged, arg)
        elif kind == 'flip':
            flip(damaged, arg)
        else:
            (magic_only if kind == 'magic_only' else flip_header)(damaged)
        try:
            got = read_all(damaged)
        except ValueError as exc:  # the one error type, naming the file, in our words
            text = str(exc)
            assert '\n' not in text and str(damaged) in text and CLEAR.search(text), text
            assert 'Error' not in text and 'ord()' not in text and 'index-sized' not in text
            outcomes[kind, arg] = text
            continue
        if storage == 'mcap' or kind != 'flip':
            assert got == expected, f'{kind} {arg}: read {len(got)} messages, not the intact'
        else:
            assert len(got) == len(expected)
        outcomes[kind, arg] = 'read'
    for kind in ('truncate', 'magic_only', 'header'):
        assert all(v != 'read' for k, v in outcomes.items() if k[0] == kind), outcomes
    if storage == 'mcap':
        assert 'truncated after 8 bytes' in outcomes['magic_only', 0]
        assert 'damaged header at offset 8' in outcomes['header', 0]
        assert 'truncated after' in outcomes['truncate', 0.5]
        assert all('damaged chunk at offset' in v for k, v in outcomes.items()
                   if k[0] == 'flip' and v != 'read'), outcomes
    else:
        assert 'not an SQLite database' in outcomes['header', 0]


def test_not_a_bag_at_all(tmp_path):
    for name, data in (('zeros.mcap', bytes(1000)), ('text.mcap', b'hello'),
                       ('zeros.db3', bytes(1000))):
        damaged = shutil.copytree(copy_bag(tmp_path / f'ok_{name}', name.split('.')[1]
                                           .replace('db3', 'sqlite3')), tmp_path / name[:-5])
        storage_file(damaged).write_bytes(data)
        with pytest.raises(ValueError, match='not an (MCAP file|SQLite database)') as info:
            bag.topics(damaged)
        assert str(storage_file(damaged)) in str(info.value)
    meta = shutil.copytree(SAMPLE, tmp_path / 'meta')
    (meta / 'metadata.yaml').write_text('{[ not yaml')
    with pytest.raises(ValueError, match='metadata.yaml: damaged'):
        bag.topics(meta)


def test_a_bag_without_metadata_or_with_an_unknown_type(tmp_path):
    no_meta = shutil.copytree(SAMPLE, tmp_path / 'no_meta')
    (no_meta / 'metadata.yaml').unlink()
    with pytest.raises(ValueError, match=f'{no_meta}: not a rosbag2 directory'):
        bag.topics(no_meta)
    unknown = bag.BagMessage('/x', 'nobody_msgs/msg/Thing', 1, b'\0\1\0\0', tmp_path / 'b')
    with pytest.raises(ValueError, match=r'b: /x at 1 ns is not a valid nobody_msgs/msg/Thing'):
        bag.deserialize(unknown)


def test_damaged_model_files(tmp_path):
    good = model_path('rgbd_10')
    cases = {'garbage.npz': b'not a model at all',
             'truncated.npz': Path(good).read_bytes()[:3000],
             'empty.npz': b''}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ValueError, match=f'{tmp_path / name}: not a part model'):
            load_model(tmp_path / name)
    np.savez(tmp_path / 'older.npz', filters=np.zeros(3))
    with pytest.raises(ValueError, match='older.npz: not a part model, missing'):
        load_model(tmp_path / 'older.npz')


def _pose4d(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(executable('pose4d')), *args], capture_output=True, text=True,
                          timeout=300)


def test_cli_on_a_damaged_bag_says_one_line_and_writes_nothing(tmp_path):
    damaged = copy_bag(tmp_path / 'damaged', 'mcap')
    truncate(damaged, 0.5)
    out = tmp_path / 'res' / 'table.json'
    for argv in (['eval', str(damaged), '--json', str(out)],
                 ['bench', str(damaged), '--json', str(out)]):
        run = _pose4d(*argv)
        assert run.returncode == 2, run.stderr
        errors = [line for line in run.stderr.splitlines() if 'error' in line]
        assert len(errors) == 1 and str(damaged) in errors[0], run.stderr
        assert 'Traceback' not in run.stderr
        assert not out.exists() and not list(tmp_path.glob('res/.*'))
    run = _pose4d('--debug', 'eval', str(damaged), '--json', str(out))
    assert run.returncode != 0 and 'Traceback' in run.stderr  # --debug shows it


def test_cli_with_a_damaged_model(tmp_path):
    model = tmp_path / 'm.npz'
    model.write_bytes(Path(model_path('rgbd_10')).read_bytes()[:5000])
    run = _pose4d('eval', str(SAMPLE), '--model', str(model), '--json', str(tmp_path / 'x.json'))
    assert run.returncode == 2 and 'Traceback' not in run.stderr
    assert f'{model}: not a part model' in run.stderr
    assert not (tmp_path / 'x.json').exists()


def test_replay_node_stops_on_damage_with_one_fatal_line(tmp_path):
    damaged = copy_bag(tmp_path / 'damaged', 'mcap')
    flipped = [seed for seed in range(40) if _flip_breaks(damaged, tmp_path, seed)]
    assert flipped, 'no seed damaged the bag'
    broken = tmp_path / f'flip_{flipped[0]}'
    run = subprocess.run([str(executable('replay')), '--ros-args', '-p',
                          f'replay.bag:={broken}', '-p', 'replay.rate:=0.0'],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 1, run.stdout + run.stderr
    text = run.stdout + run.stderr
    assert 'Traceback' not in text
    assert f'{storage_file(broken)}: damaged chunk at offset' in text, text
    # the two damages a user met first: cut to the MCAP magic, the header's length flipped
    for damage, words in ((magic_only, 'truncated after 8 bytes'),
                          (flip_header, 'damaged header at offset 8')):
        bad = shutil.copytree(damaged, tmp_path / damage.__name__)
        damage(bad)
        node = subprocess.run([str(executable('replay')), '--ros-args', '-p',
                               f'replay.bag:={bad}'], capture_output=True, text=True, timeout=60)
        text = node.stdout + node.stderr
        fatal = [line for line in text.splitlines() if 'FATAL' in line]
        assert node.returncode == 2 and len(fatal) == 1, text
        assert f'{storage_file(bad)}: {words}' in fatal[0] and 'Traceback' not in text, text
        out = tmp_path / 'res' / 'table.json'
        run = _pose4d('eval', str(bad), '--json', str(out))
        errors = [line for line in run.stderr.splitlines() if 'error' in line]
        assert run.returncode == 2 and len(errors) == 1, run.stderr
        assert f'{storage_file(bad)}: {words}' in errors[0] and not out.exists(), run.stderr


def _flip_breaks(intact: Path, tmp_path: Path, seed: int) -> bool:
    damaged = tmp_path / f'flip_{seed}'
    shutil.copytree(intact, damaged)
    flip(damaged, seed, n=200)
    try:
        bag.topics(damaged)  # the bag opens (else the node refuses its parameter instead)
        read_everything(damaged)
    except ValueError:
        try:
            bag.topics(damaged)
            return True
        except ValueError:
            return False
    return False
