"""Test set-up shared by the whole suite.

Before anything imports rclpy: DDS stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE), Fast
DDS uses the project's profile (config/fastdds.xml, as the Makefile and the demo do), and
this test run gets a ROS_DOMAIN_ID of its own, held by a lock file, so parallel runs on the same
machine cannot hear each other. AMENT_PREFIX_PATH defaults to this interpreter's prefix (the
project venv), where `make setup` installed the packages.
"""

from __future__ import annotations

import fcntl
import os
import shlex
import sys
import tempfile
from pathlib import Path

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# The graph's Fast DDS profile: VGA frames published best effort get through (config/fastdds.xml)
os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE',
                      str(Path(__file__).resolve().parents[1] / 'config' / 'fastdds.xml'))
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ.setdefault('RCUTILS_COLORIZED_OUTPUT', '0')


def _claim_domain_id() -> int:
    """The first free domain id in 11..100 (ids held by other runs are skipped)."""
    for domain in range(11, 101):
        path = Path(tempfile.gettempdir()) / f'pose4d_ros_test_domain_{domain}.lock'
        handle = path.open('a')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        _held.append(handle)  # keep the lock for the life of this process
        return domain
    raise RuntimeError('no free ROS_DOMAIN_ID in 11..100 for the test run')


_held: list = []
if 'POSE4D_TEST_DOMAIN_ID' not in os.environ:
    os.environ['POSE4D_TEST_DOMAIN_ID'] = str(_claim_domain_id())
os.environ['ROS_DOMAIN_ID'] = os.environ['POSE4D_TEST_DOMAIN_ID']

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / 'shared' / 'data'


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, or skip the test when this checkout has none."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f'needs the shared data at {SHARED_DATA} (absent in this checkout)')
    return SHARED_DATA


@pytest.fixture
def ros():
    """An rclpy context and a test node on this run's domain; yields a `harness.RosPeer`."""
    from harness import RosPeer

    peer = RosPeer()
    try:
        yield peer
    finally:
        peer.close()


@pytest.fixture
def fake_peer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """A stand-in for the MediaPipe worker (test/peer_fake_worker.py; no MediaPipe needed).

    Returns the command that starts it, and makes it the peer that `--peer mediapipe` starts:
    POSE4D_PEER_PYTHON becomes a script that runs it, whatever the arguments.
    """
    from pose4d_ros.peer import worker

    command = [sys.executable, str(Path(__file__).with_name('peer_fake_worker.py')),
               worker.__file__]
    python = tmp_path / 'peer_python'
    python.write_text('#!/bin/sh\nexec ' + ' '.join(shlex.quote(c) for c in command) + '\n')
    python.chmod(0o755)
    monkeypatch.setenv('POSE4D_PEER_PYTHON', str(python))
    return command
