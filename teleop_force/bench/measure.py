"""Helpers of ``teleop-force bench``: percentiles, process trees, timers.

Timing uses :func:`time.perf_counter` (wall) and :func:`time.process_time` (CPU of this
process): on a shared machine the ratio of the two says how much of a wall time was waiting
for a core.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def percentiles(values: Sequence[float] | np.ndarray, points: Iterable[float]) -> list[float]:
    """Return the given percentiles (0-100) of ``values`` (linear interpolation, as NumPy)."""
    data = np.asarray(values, dtype=float)
    return [float(np.percentile(data, p)) for p in points]


def rounded(value: float | None, digits: int = 3) -> float | None:
    """``value`` rounded to ``digits`` significant decimals after the point (None stays)."""
    return None if value is None else round(float(value), digits)


def child_pids(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux ``/proc``; empty elsewhere)."""
    children: list[int] = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return children
    for task in tasks:
        try:
            text = Path(f"/proc/{pid}/task/{task}/children").read_text()
        except OSError:
            continue
        children += [int(p) for p in text.split()]
    return children


def descendants(pid: int) -> list[int]:
    """All descendants of ``pid``, breadth first."""
    out: list[int] = []
    queue = [pid]
    while queue:
        for child in child_pids(queue.pop(0)):
            if child not in out:
                out.append(child)
                queue.append(child)
    return out


def command_line(pid: int) -> str:
    """Return the command line of ``pid`` joined by spaces (empty if unreadable)."""
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
        return raw.replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


@dataclass
class Stopwatch:
    """Wall and CPU seconds of a block (see :func:`stopwatch`)."""

    wall_s: float = 0.0
    cpu_s: float = 0.0

    @property
    def cpu_share(self) -> float:
        """CPU seconds per wall second of this process (1 = one core all the time)."""
        return self.cpu_s / self.wall_s if self.wall_s > 0 else 0.0


@contextmanager
def stopwatch() -> Iterator[Stopwatch]:
    """Measure the wall (``perf_counter``) and CPU (``process_time``) time of a block."""
    watch = Stopwatch()
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        yield watch
    finally:
        watch.wall_s = time.perf_counter() - wall
        watch.cpu_s = time.process_time() - cpu
