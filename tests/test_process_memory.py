"""Tests of teleop_force.process_memory: trimming hands freed malloc pages back."""

from __future__ import annotations

import threading

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.process_memory import MemoryTrimmer, resident_memory_mb


def test_resident_memory_is_read() -> None:
    rss = resident_memory_mb()
    assert rss is not None and 10.0 < rss < 100_000.0
    assert resident_memory_mb(2**31 - 1) is None  # no such process


@pytest.mark.parametrize("period", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_period_is_refused(period: float) -> None:
    with pytest.raises(ConfigurationError, match="period_s"):
        MemoryTrimmer(period)


def test_trim_returns_fragmented_free_memory_of_a_thread_arena() -> None:
    """Free blocks between live ones stay resident until malloc_trim gives their pages back.

    A worker thread (its own malloc arena, like Zenoh's and the estimator's threads) allocates
    ~120 MB in 4 kB blocks and frees all but every 64th: glibc cannot shrink the heap past the
    live blocks, so the process keeps the pages; one trim must give most of them back.
    """
    trimmer = MemoryTrimmer()
    if not trimmer.available:
        pytest.skip("this C library has no malloc_trim (not glibc)")
    kept: list[bytes] = []

    def churn() -> None:
        blocks = [bytes(4096) for _ in range(30_000)]
        kept.extend(blocks[::64])
        blocks.clear()

    trimmer.trim_now()
    thread = threading.Thread(target=churn)
    thread.start()
    thread.join()
    before = resident_memory_mb()
    released = trimmer.trim_now()
    after = resident_memory_mb()
    assert before is not None and after is not None
    assert released > 60.0, (before, after)
    assert trimmer.stats()["trims"] == 2
    assert len(kept) == 469


def test_thread_trims_periodically_and_stops() -> None:
    trimmer = MemoryTrimmer(period_s=0.01)
    if not trimmer.available:
        pytest.skip("this C library has no malloc_trim (not glibc)")
    trimmer.start()
    event = threading.Event()
    event.wait(0.3)
    trimmer.stop()
    stats = trimmer.stats()
    assert stats["trims"] >= 3
    assert stats["last_trim_ms"] is not None
    trims = stats["trims"]
    event.wait(0.1)
    assert trimmer.stats()["trims"] == trims  # stopped
