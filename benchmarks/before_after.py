"""Before/after figures of the optimisations in BENCHMARKS.md, measured in one run.

"Before" is the code of commit ``d99fc28`` (the estimator and the filtered-regressor loop as
they were), loaded from git next to the current code; both run on the same inputs, in
alternating blocks, so the ratio holds on a noisy machine::

    uv run teleop-force bench --no-messaging --no-replay --work-dir /tmp/tf-bench  # the model
    uv run python benchmarks/before_after.py /tmp/tf-bench/bench_model.json [IDENTIFY_SAMPLES]

The whole ``identify`` pipeline is timed on ``IDENTIFY_SAMPLES`` (default 240,000; 0 skips
it) with the old filtered regressor and wavelet evaluation patched in, then with the new.
Prints one JSON object.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

from teleop_force.bench.data import identification_recordings, palpation_arrays
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction import wavelet_network
from teleop_force.identification import pipeline as model_fitting
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig, filter_signals
from teleop_force.identification.pipeline import WaveletOptions, identify_model
from teleop_force.identification.regressor import RigidBodyRegressor
from teleop_force.robots.omni import omni_description

BEFORE = "d99fc28"
ROOT = Path(__file__).resolve().parents[1]


def load_before(path: str, name: str) -> types.ModuleType:
    """Import ``path`` as it was in commit ``BEFORE``, as module ``name``."""
    source = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{BEFORE}:{path}"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    module = types.ModuleType(name)
    module.__file__ = f"<{BEFORE}:{path}>"
    sys.modules[name] = module
    exec(compile(source, module.__file__, "exec"), module.__dict__)
    return module


def time_updates(estimator: object, rows: list, n: int) -> np.ndarray:
    """Time ``n`` updates one by one [µs]."""
    out = np.empty(n)
    clock = time.perf_counter_ns
    update = estimator.update  # type: ignore[attr-defined]
    for k in range(n):
        t, q, tau = rows[k % len(rows)]
        start = clock()
        update(t, q, tau)
        out[k] = clock() - start
    return out / 1e3


def main() -> int:
    """Measure and print the before/after figures."""
    model = DynamicModel.load(sys.argv[1])
    old_estimation = load_before("teleop_force/estimation/estimator.py", "before_estimation")
    old_regressor = load_before(
        "teleop_force/identification/filtered_regressor.py", "before_filtered_regressor"
    )
    arrays = palpation_arrays(12.0)
    rows = [
        (float(t), np.array(q), np.array(tau))
        for t, q, tau in zip(arrays["t_s"], arrays["q_rad"], arrays["tau_nm"], strict=True)
    ]
    estimators = {"before": old_estimation.ForceEstimator(model), "after": ForceEstimator(model)}
    for estimator in estimators.values():
        time_updates(estimator, rows[:500], 500)
    samples: dict[str, list[np.ndarray]] = {"before": [], "after": []}
    for block in range(10):
        for name, estimator in estimators.items():
            estimator.reset()  # type: ignore[attr-defined]
            chunk = rows[block * 1000 : (block + 1) * 1000]
            samples[name].append(time_updates(estimator, chunk, 1000))
    result: dict[str, object] = {}
    for name, parts in samples.items():
        data = np.concatenate(parts)
        result[f"estimate_step_p50_us_{name}"] = round(float(np.percentile(data, 50)), 2)
        result[f"estimate_step_p99_us_{name}"] = round(float(np.percentile(data, 99)), 2)
    # the same numbers, before and after, on one stream
    new, old = ForceEstimator(model), old_estimation.ForceEstimator(model)
    diff = max(
        float(np.max(np.abs(
            new.update(*r).tau_model_filtered_nm - old.update(*r).tau_model_filtered_nm
        )))
        for r in rows[:3000]
    )  # fmt: skip
    result["estimate_max_difference_nm"] = diff

    (recording,) = identification_recordings(20.0, 20_000)[:1]
    description = omni_description()
    regressor = RigidBodyRegressor(description)
    base = regressor.find_base_parameters()
    config = FilterConfig()
    walls: dict[str, list[float]] = {"before": [], "after": []}
    outputs = {}
    for _ in range(3):
        for name, function in (("before", old_regressor.filter_signals), ("after", filter_signals)):
            start = time.perf_counter()
            outputs[name] = function(
                recording.t_s, recording.q_rad, recording.tau_nm, regressor, base, config
            )
            walls[name].append(time.perf_counter() - start)
    for name, wall in walls.items():
        result[f"filter_signals_x_realtime_{name}"] = round(20.0 / min(wall), 2)
    result["filter_signals_max_difference"] = float(
        np.max(np.abs(outputs["before"].rigid_regressor - outputs["after"].rigid_regressor))
    )
    samples = int(sys.argv[2]) if len(sys.argv) > 2 else 240_000
    if samples:
        old_network = load_before("teleop_force/friction/wavelet_network.py", "before_wn")
        recordings = identification_recordings(44.0, samples // 2)
        new_psi, new_filter = wavelet_network.psi_block, model_fitting.filter_signals
        for name, psi, filt in (
            ("before", old_network.psi_block, old_regressor.filter_signals),
            ("after", new_psi, new_filter),
        ):
            wavelet_network.psi_block, model_fitting.filter_signals = psi, filt
            start = time.perf_counter()
            identify_model(recordings, description, "wn", wavelet=WaveletOptions("batch"))
            wall = time.perf_counter() - start
            result[f"identify_pipeline_x_realtime_{name}"] = round(samples / 1000 / wall, 2)
        wavelet_network.psi_block, model_fitting.filter_signals = new_psi, new_filter
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
