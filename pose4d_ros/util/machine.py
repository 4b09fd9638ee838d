"""The facts a timing or a trained model records: the commit, the command, the machine and its
thread settings."""

from __future__ import annotations

import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path


def git_commit() -> str:
    try:
        root = Path(__file__).resolve().parents[2]
        out = subprocess.run(['git', '-C', str(root), 'rev-parse', '--short', 'HEAD'],
                             capture_output=True, text=True, timeout=5)
        return out.stdout.strip() if out.returncode == 0 else ''
    except (OSError, subprocess.SubprocessError):
        return ''


def command_line(verb: str) -> str:
    """`pose4d VERB ...` as this process was started, or '' when it was not started so."""
    if sys.argv[1:2] != [verb]:
        return ''
    return f'pose4d {verb} ' + ' '.join(shlex.quote(a) for a in sys.argv[2:])


def machine() -> dict[str, str | int]:
    """Cores, CPU model and the thread settings that matter for timing."""
    import numba

    from pose4d_ros.core.threads import blas_threads

    cpu = platform.processor() or ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return {'cores': os.cpu_count() or 0, 'cpu': cpu, 'python': platform.python_version(),
            'numba_threads': int(numba.get_num_threads()),
            'blas_threads': ', '.join(f'{k}={v}' for k, v in blas_threads().items()) or 'n/a',
            'load_average': ' '.join(f'{x:.2f}' for x in os.getloadavg())}
