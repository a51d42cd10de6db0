import math

import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.service.accuracy import AccuracyConfig, ForceAccuracy
from teleop_force.transport.stream_stats import LatencyHistogram, RateMeter, SequenceTracker


def test_sequence_gaps_are_losses_and_backward_jumps_are_restarts():
    seqs = SequenceTracker()
    assert seqs.observe(7).lost == 0
    assert seqs.observe(8).lost == 0
    assert seqs.observe(11).lost == 2
    assert seqs.observe(11).duplicate
    event = seqs.observe(3)
    assert event.restarted and event.lost == 0
    assert seqs.observe(4).lost == 0
    assert seqs.to_dict() == {"received": 6, "lost": 2, "restarts": 1, "duplicates": 1}


def test_sequence_wraps_at_2_32():
    seqs = SequenceTracker()
    seqs.observe(2**32 - 2)
    assert seqs.observe(2**32 - 1).lost == 0
    assert seqs.observe(1).lost == 1
    assert seqs.restarts == 0


def test_huge_forward_jump_is_a_restart():
    seqs = SequenceTracker(max_gap=1000)
    seqs.observe(0)
    assert seqs.observe(5000).restarted
    assert seqs.lost == 0


def test_latency_histogram_percentiles():
    histogram = LatencyHistogram()
    assert histogram.summary_ms() == {"p50": None, "p99": None, "max": None, "count": 0}
    for k in range(1, 201):
        histogram.add(k * 1e-3)
    histogram.add(math.nan)
    histogram.add(-1e-6)
    assert histogram.count == 201 and histogram.negative == 1
    summary = histogram.summary_ms()
    assert summary["max"] == 200.0
    assert summary["p50"] == pytest.approx(100.0, rel=0.01)  # exact to the bin width
    assert summary["p99"] == pytest.approx(198.0, rel=0.01)
    one = LatencyHistogram()
    one.add(0.4e-3)
    assert one.summary_ms()["p50"] == pytest.approx(0.4, rel=0.006)
    values = np.random.default_rng(0).lognormal(-7.0, 1.0, 20_000)
    big = LatencyHistogram()
    for v in values:
        big.add(float(v))
    assert big.percentile_s(99.0) == pytest.approx(np.percentile(values, 99.0), rel=0.01)
    with pytest.raises(ConfigurationError):
        LatencyHistogram(min_s=0.0)


def test_rate_meter_counts():
    meter = RateMeter(window_s=0.01)
    meter.tick(5)
    assert meter.total == 5
    assert meter.mean_rate_hz > 0.0
    with pytest.raises(ConfigurationError):
        RateMeter(0.0)


def test_accuracy_pairs_by_seq_in_any_order():
    accuracy = ForceAccuracy(AccuracyConfig(contact_threshold_n=0.1))
    accuracy.add_true(1, (0.0, -1.0, 0.0))
    accuracy.add_estimate(1, (0.0, -1.1, 0.0))
    accuracy.add_estimate(2, (0.0, -0.9, 0.0))  # estimate first
    accuracy.add_true(2, (0.0, -1.0, 0.0))
    accuracy.add_true(3, (0.0, 0.0, 0.0))  # no contact
    accuracy.add_estimate(3, (0.0, 0.05, 0.0))
    accuracy.add_estimate(4, (math.nan, math.nan, math.nan))
    summary = accuracy.summary()
    assert summary["paired_samples"] == 3
    assert summary["contact_samples"] == 2
    assert summary["no_force_estimates"] == 1
    assert summary["relative_rms_error"] == pytest.approx(0.1)
    seq, estimate, true = accuracy.arrays()
    assert seq.tolist() == [1, 2, 3]
    assert estimate.shape == true.shape == (3, 3)
