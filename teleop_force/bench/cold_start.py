"""``bench``'s cold start: from the command to the first estimate, with an empty numba cache.

Runs the headless demo twice on one new, empty ``NUMBA_CACHE_DIR``: the first run compiles
every kernel group (:mod:`teleop_force.process.warm_up`), the second only loads them. The
figures are the demo summary's own: ``first_estimate_s`` (from the command's process start
to the first estimate the supervisor received), the warm-up's time per group, and the share
of the slave's joint states the service estimated.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from teleop_force.bench.messaging import run_demo


def cold_start_figures(summary: dict[str, Any], prefix: str) -> dict[str, Any]:
    """Return one run's figures under ``<prefix>_...`` (keys carry their units)."""
    warm_up = summary.get("warm_up") or {}
    coverage = summary.get("estimate_coverage") or {}
    return {
        f"{prefix}_first_estimate_s": summary.get("first_estimate_s"),
        f"{prefix}_warm_up_s": warm_up.get("seconds"),
        f"{prefix}_warm_up_cached": warm_up.get("cached"),
        f"{prefix}_compile_s_by_group": {
            name: group.get("seconds") for name, group in (warm_up.get("groups") or {}).items()
        }
        or None,
        f"{prefix}_up_after_s": summary.get("up_after_s"),
        f"{prefix}_estimated_fraction": coverage.get("estimated_fraction"),
    }


def measure_cold_start(
    duration_s: float, model_path: Path | None, log: Callable[[str], None]
) -> dict[str, Any]:
    """Run the demo cold then warm on a new numba cache; return both runs' figures."""
    with tempfile.TemporaryDirectory(prefix="teleop-bench-numba-") as cache:
        env = {"NUMBA_CACHE_DIR": cache}
        log(f"cold start: headless demo for {duration_s:g} s on an empty numba cache")
        cold = run_demo(duration_s, model_path, env=env)
        log(f"  first estimate {cold.get('first_estimate_s')} s after the command")
        log("  again, on the cache the first run filled")
        warm = run_demo(duration_s, model_path, env=env)
        log(f"  first estimate {warm.get('first_estimate_s')} s after the command")
    return {**cold_start_figures(cold, "cold_start"), **cold_start_figures(warm, "warm_start")}
