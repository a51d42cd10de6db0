import numpy as np

from teleop_force.io.interchange_csv import Recording
from teleop_force.residual.acceptance import (
    TEST_BLOCKS,
    sign_flip_p_value,
    trace_residual_tested,
)
from teleop_force.robots.registry import resolve_robot


def _sweeps(cable: bool, seed: int = 0) -> Recording:
    """Three slow sweeps of one joint; with ``cable`` a position-dependent torque."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 72.0, 0.005)
    phase = np.mod(t, 24.0)
    q = np.where(phase < 12, -1.4 + 0.4 * phase, -1.4 + 0.4 * (24 - phase))
    qd = np.gradient(q, t)
    tau = 0.02 * np.sign(qd) + 0.003 * qd + 0.01
    if cable:
        tau = tau + 0.04 * np.sin(1.3 * q) + 0.01 * np.cos(2 * q) * np.sign(qd)
    tau = tau + rng.normal(0, 0.001, t.size)
    return Recording(t, q[:, None], tau[:, None])


def test_sign_flip_p_value_is_exact_and_at_most_uniform_under_the_null() -> None:
    assert sign_flip_p_value(np.ones(TEST_BLOCKS)) == 1.0 / 2**TEST_BLOCKS
    assert sign_flip_p_value(-np.ones(TEST_BLOCKS)) == 1.0
    assert sign_flip_p_value(np.ones(3)) == 1.0  # not the test's shape: never accepted
    rng = np.random.default_rng(0)
    # symmetric about a value <= 0 (a fixed prediction that does not predict): P(p <= a) <= a
    p = np.array([sign_flip_p_value(rng.normal(-0.2, 1.0, TEST_BLOCKS)) for _ in range(400)])
    for level in (0.01, 0.05, 0.2):
        assert np.mean(p <= level) <= level + 2.5 * np.sqrt(level * (1 - level) / 400)


def test_a_real_effect_passes_the_held_out_test() -> None:
    report = trace_residual_tested([_sweeps(cable=True)], resolve_robot("none", 1))
    assert report.tested and report.effects
    assert all(t["accepted"] == (t["p_value"] <= t["level"]) for t in report.tested)
    assert len(report.effects) == sum(t["accepted"] for t in report.tested)
    assert report.test_after is not None and report.test_before is not None
    assert report.test_after[0] < 0.5 * report.test_before[0]
    assert report.to_json()["tested"] == [dict(t) for t in report.tested]


def test_a_clean_recording_keeps_no_effect() -> None:
    report = trace_residual_tested([_sweeps(cable=False)], resolve_robot("none", 1))
    assert report.effects == ()
    assert report.failed is None and report.fallbacks == ()
