"""Quiet logs: a progress bar on a terminal only; in a log file, a line every few seconds."""

from __future__ import annotations

import io
import subprocess

from harness import executable

from pose4d_ros.util import progress as _progress
from pose4d_ros.util.progress import LOG_PERIOD_S, LineProgress, progress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_bar_on_a_terminal_and_lines_elsewhere():
    from tqdm import tqdm

    assert isinstance(progress(range(3), 'x', file=_Terminal()), tqdm)
    assert isinstance(progress(range(3), 'x', file=io.StringIO()), LineProgress)


def test_twenty_minutes_of_frames_make_a_small_log(monkeypatch):
    """A 20-minute job, 32 frames a second, logged to a file: a line per LOG_PERIOD_S."""
    now = [0.0]
    monkeypatch.setattr(_progress.time, 'monotonic', lambda: now[0])
    log = io.StringIO()
    frames = 20 * 60 * 32
    for _ in progress(range(frames), 'rgbd', file=log):
        now[0] += 1 / 32
    lines = log.getvalue().splitlines()
    assert len(lines) == int(20 * 60 / LOG_PERIOD_S) + 1  # and the last one
    assert len(log.getvalue()) < 100_000 and '\r' not in log.getvalue()
    assert lines[0] == f'rgbd: 320/{frames} frames in 10 s (32.0/s), about 1190 s left'
    assert lines[-1] == f'rgbd: {frames}/{frames} frames in 1200 s (32.0/s), done'


def test_updated_by_hand_and_closed_once(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(_progress.time, 'monotonic', lambda: now[0])
    log = io.StringIO()
    with progress(desc='cad60-to-bag', file=log) as bar:
        for n in range(1, 40):
            now[0] += 1.0
            bar.update(n - bar.n)
        bar.close()
    assert log.getvalue().splitlines() == [
        'cad60-to-bag: 10 frames in 10 s (1.0/s)', 'cad60-to-bag: 20 frames in 20 s (1.0/s)',
        'cad60-to-bag: 30 frames in 30 s (1.0/s)', 'cad60-to-bag: 39 frames in 39 s (1.0/s), done']


def test_eval_logged_to_a_file_has_no_bar(tmp_path):
    """`pose4d eval` with stderr in a file: plain lines, no carriage-return redraws."""
    from pose4d_ros.graph.run import default_bag

    log = tmp_path / 'eval.log'
    with log.open('w') as err:
        run = subprocess.run([str(executable('pose4d')), 'eval', str(default_bag()),
                              '--json', str(tmp_path / 'eval.json'), '--model', 'rgbd_10'],
                             stdout=subprocess.DEVNULL, stderr=err, timeout=600)
    text = log.read_text()
    assert run.returncode == 0, text
    assert '\r' not in text and '\x1b' not in text
    assert 'rgbd: 45/45 frames in' in text and text.count('\n') < 20, text
