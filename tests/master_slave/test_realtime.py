"""RateLoop: sleeps to each deadline, counts overruns and the ticks a stall makes it miss."""

from __future__ import annotations

import gc
import sys

import pytest

from master_slave.process_args import loop_config_from_args
from master_slave.realtime import LoopConfig, RateLoop, set_timer_slack_ns
from teleop_force.errors import ConfigurationError


class FakeTime:
    """A clock that only ``sleep`` (or the test) moves forward."""

    def __init__(self) -> None:
        self.now_s = 100.0
        self.sleeps: list[float] = []

    def clock(self) -> float:
        return self.now_s

    def sleep(self, duration_s: float) -> None:
        self.sleeps.append(duration_s)
        self.now_s += duration_s


def fake_loop(**config) -> tuple[RateLoop, FakeTime]:
    fake = FakeTime()
    config.setdefault("timer_slack_ns", 0)
    loop = RateLoop(LoopConfig(**config), clock=fake.clock, sleep=fake.sleep)
    loop.start()
    return loop, fake


def test_sleeps_exactly_to_each_deadline_without_spinning():
    loop, fake = fake_loop(rate_hz=1000.0)
    assert loop.wait() == 0 and fake.sleeps == []  # tick 0 is due at the start
    fake.now_s += 0.0003  # the tick's work
    assert loop.wait() == 1
    assert fake.sleeps == [pytest.approx(0.0007)]
    assert loop.overruns == 0 and loop.missed_ticks == 0
    assert LoopConfig().spin_s == 0.0  # no busy-waiting by default


def test_a_late_tick_is_an_overrun_and_the_loop_catches_up_without_skipping():
    loop, fake = fake_loop(rate_hz=1000.0, max_lag_s=0.1)
    loop.wait()
    stamp0 = loop.stamp_ns
    fake.now_s += 0.0105  # a 10.5 ms stall inside tick 0
    ticks = [loop.wait() for _ in range(10)]
    assert ticks == list(range(1, 11))  # no tick skipped: they run back to back
    assert fake.sleeps == []
    # ticks 1..9 started more than one period late (tick 10 is 0.5 ms late)
    assert loop.overruns == 9 and loop.missed_ticks == 0 and loop.resyncs == 0
    assert loop.stamp_ns - stamp0 == 10 * 1_000_000  # stamps stay nominal
    loop.wait()
    assert fake.sleeps == [pytest.approx(0.0005)]  # on schedule again
    stats = loop.stats()
    assert stats["ticks"] == 12 and stats["overruns"] == 9
    assert stats["overrun_fraction"] == pytest.approx(9 / 12, abs=1e-6)
    assert stats["expected_ticks"] == pytest.approx(11.0, abs=0.01)


def test_a_stall_beyond_max_lag_resyncs_and_counts_every_missed_tick():
    loop, fake = fake_loop(rate_hz=1000.0, max_lag_s=0.01)
    for _ in range(5):
        loop.wait()
        fake.now_s += 0.0002
    fake.now_s += 0.2503  # a 250 ms stall in tick 4
    assert loop.wait() == 5
    assert loop.resyncs == 1 and loop.overruns == 1
    # tick 5 was due at 5 ms and runs at 254.5 ms: the deadlines of ticks 6..254 were missed
    assert loop.missed_ticks == 249
    loop.wait()  # re-anchored: the next tick is due one period after the resync
    assert fake.sleeps[-1] == pytest.approx(0.001)
    stats = loop.stats()
    assert stats["ticks"] + stats["missed_ticks"] == pytest.approx(stats["expected_ticks"], abs=1.0)
    assert stats["ticks_fraction"] == pytest.approx(7 / 255.5, rel=1e-3)


def test_a_sleep_that_overshoots_a_whole_period_counts_as_an_overrun():
    fake = FakeTime()

    def late_sleep(duration_s: float) -> None:
        fake.now_s += duration_s + 0.0015  # the machine was busy: woke 1.5 ms late

    loop = RateLoop(LoopConfig(timer_slack_ns=0), clock=fake.clock, sleep=late_sleep)
    loop.start()
    loop.wait()
    loop.wait()
    assert loop.overruns == 1


def test_spinning_is_still_available_on_request():
    fake = FakeTime()
    reads = []

    def clock() -> float:  # each read while spinning moves time on by 10 us
        reads.append(fake.now_s)
        fake.now_s += 1e-5
        return fake.now_s

    loop = RateLoop(LoopConfig(spin_s=1e-4, timer_slack_ns=0), clock=clock, sleep=fake.sleep)
    loop.start()
    loop.wait()
    loop.wait()
    assert fake.sleeps == [pytest.approx(0.0009 - 2e-5)]  # sleeps to 0.1 ms before the deadline
    assert len(reads) >= 10  # ... then spins the rest


def test_start_freezes_the_heap_and_lowers_the_timer_slack():
    loop = RateLoop(LoopConfig(rate_hz=1000.0, freeze_gc=True))
    try:
        loop.start()
        assert gc.get_freeze_count() > 0
        stats = loop.stats()
        assert stats["gc_frozen_objects"] > 0
        if sys.platform.startswith("linux"):
            assert loop.timer_slack_ns == 1000 == stats["timer_slack_ns"]
    finally:
        gc.unfreeze()
        set_timer_slack_ns(50_000)  # the default of a Linux thread


def test_processes_freeze_their_heap_other_loops_do_not():
    from master_slave.slave import build_parser

    assert loop_config_from_args(build_parser().parse_args([])).freeze_gc
    assert not LoopConfig().freeze_gc


def test_config_ranges():
    with pytest.raises(ConfigurationError):
        LoopConfig(timer_slack_ns=-1)
    with pytest.raises(ConfigurationError):
        LoopConfig(spin_s=0.01)
    with pytest.raises(ConfigurationError):
        LoopConfig(max_lag_s=0.0005)
