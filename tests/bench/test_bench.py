"""Smoke test of ``teleop-force bench --quick --json``: one JSON object, keys and types.

Performance is reported, never asserted: no figure is compared with a goal here.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from teleop_force.bench.measure import percentiles
from teleop_force.process.memory import peak_rss_mb
from teleop_force.process.warm_up import KERNEL_GROUPS

NUMBERS = (
    "estimate_step_p50_us",
    "estimate_step_p99_us",
    "rnea_us",
    "estimate_step_vs_rnea",
    "identify_batch_x_realtime",
    "identify_adaptive_x_realtime",
    "identify_pipeline_x_realtime",
    "identify_filter_signals_x_realtime",
    "replay_x_realtime",
    "service_peak_rss_mb",
)
MESSAGING = (
    "latency_master_to_slave_p50_ms",
    "latency_master_to_slave_p99_ms",
    "latency_slave_to_estimate_p50_ms",
    "latency_slave_to_estimate_p99_ms",
    "latency_end_to_end_p99_ms",
    "messages_lost",
)
SCALING = (
    "estimate_step_p50_us_by_wavelets",
    "estimate_step_p99_us_by_wavelets",
    "replay_x_realtime_by_wavelets",
    "replay_peak_rss_mb_by_wavelets",
    "replay_x_realtime_by_length_s",
    "replay_peak_rss_mb_by_length_s",
)


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


@pytest.fixture(scope="module")
def quick_run() -> dict:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "teleop_force.cli.main",
            "bench",
            "--quick",
            "--json",
            "--no-messaging",
        ],
        capture_output=True,
        text=True,
        timeout=480,  # the cold start compiles every kernel group once
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    assert len(lines) == 1, "stdout must hold exactly one JSON object"
    return json.loads(lines[0])


@pytest.mark.zenoh  # the replay figures run a service on a loopback Zenoh session
def test_quick_bench_prints_the_figures(quick_run: dict) -> None:
    result = quick_run
    assert result["quick"] is True
    for key in NUMBERS:
        assert _number(result[key]), key
    for key in MESSAGING:  # skipped with --no-messaging, but present
        assert key in result and result[key] is None, key
    for key in SCALING:
        table = result[key]
        assert isinstance(table, dict) and table, key
        assert all(isinstance(k, str) and _number(v) for k, v in table.items()), key
    assert set(result["estimate_step_p50_us_by_wavelets"]) == {"100", "300", "1000"}
    counts = result["model_wavelets_per_joint"]
    assert isinstance(counts, list) and len(counts) == 3 and all(isinstance(c, int) for c in counts)
    assert result["model_found_effects"] == 2
    assert isinstance(result["load_average_start"], list)
    for goal in result["goals"].values():
        assert goal["met"] in (True, False, None)


@pytest.mark.zenoh
def test_quick_bench_measures_the_cold_start(quick_run: dict) -> None:
    # The first demo compiled every group ahead (an empty cache), the second found them cached;
    # in both, the first estimate came, and the service estimated the slave's joint states
    # from the first one on (nothing lost while compiling).
    assert quick_run.get("cold_start_error") is None
    assert quick_run["cold_start_warm_up_cached"] is False
    groups = quick_run["cold_start_compile_s_by_group"]
    assert set(groups) == {g.name for g in KERNEL_GROUPS}
    assert all(_number(seconds) and seconds > 0 for seconds in groups.values())
    assert quick_run["warm_start_warm_up_cached"] is True
    assert quick_run["warm_start_compile_s_by_group"] is None
    for run in ("cold_start", "warm_start"):
        assert _number(quick_run[f"{run}_first_estimate_s"]), run
        assert quick_run[f"{run}_estimated_fraction"] >= 0.99, run
        assert set(quick_run[f"{run}_up_after_s"]) == {"recorder", "service", "slave", "master"}


def test_bench_rejects_bad_options() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "teleop_force.cli.main", "bench", "--messaging-duration", "-1"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 2
    assert "--messaging-duration" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_helpers() -> None:
    assert percentiles([1.0, 2.0, 3.0], (50,)) == [2.0]
    peak = peak_rss_mb()
    assert peak is not None and peak > 1.0


def test_only_selects_the_parts() -> None:
    import argparse

    from teleop_force.bench.main import add_bench_arguments, options_from_args
    from teleop_force.errors import ConfigurationError

    parser = argparse.ArgumentParser()
    add_bench_arguments(parser)
    only = options_from_args(parser.parse_args(["--only", "identification"]))
    assert not (only.estimation or only.replay or only.messaging)
    both = options_from_args(parser.parse_args(["--only", "estimation,replay", "--quick"]))
    assert both.estimation and both.replay and not both.messaging and both.quick
    everything = options_from_args(parser.parse_args([]))
    assert everything.estimation and everything.replay and everything.messaging
    assert (
        everything.cold_start
        and not options_from_args(parser.parse_args(["--no-cold-start"])).cold_start
    )
    with pytest.raises(ConfigurationError, match="--only"):
        options_from_args(parser.parse_args(["--only", "identification,bogus"]))


def test_estimation_step_timing_on_a_robot_with_more_model_joints_than_motors() -> None:
    """The MTM's pinocchio model has 9 joints for 7 motors: the rnea reference uses nv."""
    from teleop_force.bench.estimation import time_estimation_step
    from teleop_force.identification.pipeline import identify_model
    from teleop_force.io.interchange_csv import Recording
    from teleop_force.robots.dvrk_mtm import dvrk_mtm_description

    description = dvrk_mtm_description()
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 6.0, 0.005)
    phases = rng.uniform(0, 2 * np.pi, 7)
    q = 0.3 * np.sin(2 * np.pi * 0.4 * t[:, None] + phases)
    tau = 0.05 * np.cos(2 * np.pi * 0.4 * t[:, None] + phases) + rng.normal(0, 1e-3, (t.size, 7))
    model, _ = identify_model([Recording(t, q, tau)], description, "model-cv", offsets=True)
    timing = time_estimation_step(model, t, q, tau, samples=200, warmup=50)
    assert timing.samples == 200
    assert timing.rnea_us > 0.0 and timing.p50_us > 0.0
