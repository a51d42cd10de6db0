"""The force service's counters, each the source of its part of the ``service/stats`` JSON."""

import math
import time

from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.service.counters import (
    MAX_COUNTED_KEYS,
    OTHER_KEYS,
    ControlCounters,
    EstimateCounters,
    JointStateCounters,
    MalformedCounter,
)


def test_malformed_keys_beyond_the_cap_are_counted_together():
    counter = MalformedCounter()
    for k in range(10 * MAX_COUNTED_KEYS):
        counter.count(f"/device_{k}/setpoint_js", ValueError("bad"))
    counter.count("/device_0/setpoint_js", ValueError("again"))  # a key already counted
    table = counter.to_dict()["by_key"]
    assert len(table) == MAX_COUNTED_KEYS + 1
    assert table[OTHER_KEYS] == 9 * MAX_COUNTED_KEYS
    assert table["/device_0/setpoint_js"] == 2
    assert counter.dropped == counter.to_dict()["dropped"] == 10 * MAX_COUNTED_KEYS + 1
    assert counter.last == "/device_0/setpoint_js: again"
    counter.count("/new/measured_js", MemoryError("x"))
    assert counter.last == f"{OTHER_KEYS}: x"


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 30), max_size=200), st.integers(1, 10))
def test_the_malformed_table_is_bounded_and_loses_no_count(key_ids, cap):
    counter = MalformedCounter(max_keys=cap)
    first_keys: list[str] = []
    for k in key_ids:
        key = f"k{k}"
        if key not in first_keys:
            first_keys.append(key)
        counter.count(key, ValueError("bad"))
    stats = counter.to_dict()
    assert stats["dropped"] == len(key_ids) == sum(stats["by_key"].values())
    kept = first_keys[:cap]  # the first keys seen are the ones counted apart
    assert set(stats["by_key"]) - {OTHER_KEYS} == set(kept)
    for key in kept:
        assert stats["by_key"][key] == sum(f"k{k}" == key for k in key_ids)
    assert (OTHER_KEYS in stats["by_key"]) == (len(first_keys) > cap)
    stats["by_key"].clear()  # a copy: the table itself is untouched
    assert counter.dropped == len(key_ids)


def test_the_empty_counters_report_zero_and_null():
    assert MalformedCounter().to_dict() == {"dropped": 0, "by_key": {}, "last": ""}
    assert ControlCounters().to_dict() == {"requests": 0, "refused": 0, "last_refusal": ""}
    estimates = EstimateCounters(3)
    assert estimates.to_dict() == {"published": 0, "singular": 0, "errors": 0, "last_error": ""}
    assert estimates.on_ground_fraction() is None
    assert estimates.on_ground_fraction_per_joint() == [None, None, None]
    assert estimates.last_estimate_dict() is None
    js = JointStateCounters().to_dict(stream_restarts=2, backlog=5)
    assert list(js) == [
        "received", "lost", "restarts", "duplicates", "stream_restarts", "backlog",
        "overflow_dropped", "rate_hz", "mean_rate_hz",
    ]  # fmt: skip
    assert (js["stream_restarts"], js["backlog"], js["overflow_dropped"]) == (2, 5, 0)


def test_published_estimates_add_up():
    counters = EstimateCounters(3)
    started = time.perf_counter()
    flags = [(True, True, True), (True, False, True), (True, True, True), (False,) * 3]
    for k, on_ground in enumerate(flags):
        f = [math.nan, math.nan, math.nan] if k == 3 else [1.0, 2.0, 3.0]
        mask = sum(1 << j for j, flag in enumerate(on_ground) if flag)
        counters.count_published(100 + k, f, mask, 3, k == 3, time.time_ns(), started)
    counters.count_error("boom")
    assert counters.to_dict() == {
        "published": 4, "singular": 1, "errors": 1, "last_error": "boom",
    }  # fmt: skip
    assert counters.on_ground_fraction() == 0.5
    assert counters.on_ground_fraction_per_joint() == [0.75, 0.5, 0.75]
    assert counters.last_estimate_dict() == {"source_seq": 103, "f_n": [None, None, None]}
    assert counters.latency.count == counters.processing.count == 4


def test_control_refusals_keep_the_last_reason():
    controls = ControlCounters()
    controls.requests += 2
    controls.count_refusal("first")
    controls.count_refusal("second")
    assert controls.to_dict() == {"requests": 2, "refused": 2, "last_refusal": "second"}
