"""The ROS-user path: both packages built with colcon, as the README tells ROS users.

A temporary workspace gets a copy of this checkout at src/pose4d_ros; the project venv (ROS 2
Jazzy from wheels) is the underlay. Takes ~15 s, so it is marked slow; CI runs it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

pytestmark = pytest.mark.slow


def _copy_checkout(dest: Path) -> None:
    ignore = shutil.ignore_patterns('.venv', 'build', 'install', 'log', 'out', '.git',
                                    '__pycache__', '*.egg-info', '.pytest_cache', '.ruff_cache')
    shutil.copytree(REPO, dest, ignore=ignore)


def test_colcon_builds_both_packages(tmp_path):
    if shutil.which('colcon', path=str(Path(sys.prefix) / 'bin')) is None:
        pytest.fail('colcon is not installed in the project venv (requirements/dev.txt)')
    ws = tmp_path / 'ws'
    _copy_checkout(ws / 'src' / 'pose4d_ros')
    venv = Path(sys.prefix)
    env = dict(os.environ, VIRTUAL_ENV=str(venv), PATH=f'{venv / "bin"}:{os.environ["PATH"]}',
               AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv))
    build = subprocess.run(
        ['colcon', 'build', '--base-paths', 'src/pose4d_ros', 'src/pose4d_ros/pose4d_msgs',
         '--event-handlers', 'console_direct-'],
        cwd=ws, env=env, capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout + build.stderr
    assert 'Summary: 2 packages finished' in build.stdout
    install = ws / 'install'
    for exe in ('pose4d', 'replay', 'recorder'):
        assert os.access(install / 'pose4d_ros' / 'lib' / 'pose4d_ros' / exe, os.X_OK)
    probe = (
        'import pose4d_msgs, pose4d_ros\n'
        'from pose4d_msgs.msg import Joint, JointArray\n'
        'from ament_index_python.packages import get_package_prefix\n'
        'from rclpy.serialization import serialize_message, deserialize_message\n'
        'm = JointArray(joints=[Joint(name="head", source=Joint.INFERRED)])\n'
        'assert deserialize_message(serialize_message(m), JointArray) == m\n'
        'print(pose4d_msgs.__file__)\n'
        'print(pose4d_ros.__file__)\n'
        'print(get_package_prefix("pose4d_ros"))\n'
    )
    run = subprocess.run(['bash', '-c', f'source install/setup.bash && python -c \'{probe}\''],
                         cwd=ws, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    msgs_file, ros_file, prefix = run.stdout.split()
    assert msgs_file.startswith(str(install / 'pose4d_msgs'))
    assert ros_file.startswith(str(install / 'pose4d_ros'))
    assert prefix == str(install / 'pose4d_ros')
