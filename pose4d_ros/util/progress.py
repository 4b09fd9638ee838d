"""Progress of the long offline jobs, on stderr: a bar on a terminal, a few lines in a log.

A tqdm bar redraws itself many times a second; in a log file or a pipe every redraw is kept,
and a 20-minute `pose4d eval` wrote megabytes of them. So the bar is only drawn when stderr is
a terminal; otherwise `LineProgress` writes one plain line at most every `LOG_PERIOD_S` seconds
(done, total, rate, time left) and one when the job ends.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TextIO

LOG_PERIOD_S = 10.0


def log(message: str) -> None:
    """One line of an offline job's log, on stderr."""
    print(message, file=sys.stderr, flush=True)


def progress(iterable: Iterable | None = None, desc: str = '', total: int | None = None, *,
             unit: str = 'frame', disable: bool = False, file: TextIO | None = None) -> Any:
    """A progress counter over `iterable` (or updated by hand: `update(n)`, `n`, `close()`,
    and usable in a `with`): a tqdm bar when `file` (default stderr) is a terminal, else a
    `LineProgress`."""
    file = file or sys.stderr
    if total is None and hasattr(iterable, '__len__'):
        total = len(iterable)
    if file.isatty():
        from tqdm import tqdm

        return tqdm(iterable, desc=desc, total=total, unit=unit, leave=False, disable=disable,
                    dynamic_ncols=True, file=file)
    return LineProgress(iterable, desc, total, unit=unit, disable=disable, file=file)


class LineProgress:
    """Progress as plain lines, at most one every `period_s` seconds, and one at the end."""

    def __init__(self, iterable: Iterable | None, desc: str, total: int | None, *,
                 unit: str = 'frame', disable: bool = False, file: TextIO | None = None,
                 period_s: float = LOG_PERIOD_S) -> None:
        self.iterable = iterable
        self.desc = desc
        self.total = total
        self.unit = unit
        self.disable = disable
        self.file = file or sys.stderr  # the stream of the moment, not of the import
        self.period_s = period_s
        self.n = 0
        self._start = self._last = time.monotonic()
        self._closed = False

    def __iter__(self) -> Iterator:
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self._last >= self.period_s:
            self._last = now
            self._write(now)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._write(time.monotonic(), done=True)

    def _write(self, now: float, *, done: bool = False) -> None:
        if self.disable:
            return
        elapsed = now - self._start
        rate = self.n / elapsed if elapsed > 0 else 0.0
        count = f'{self.n}/{self.total}' if self.total else f'{self.n}'
        text = f'{self.desc}: {count} {self.unit}s in {elapsed:.0f} s ({rate:.1f}/s)'
        if done:
            text += ', done'
        elif self.total and rate > 0:
            text += f', about {(self.total - self.n) / rate:.0f} s left'
        print(text, file=self.file, flush=True)
