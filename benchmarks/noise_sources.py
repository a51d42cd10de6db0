"""Which measurement noise bounds the estimator's bandwidth: encoder counts or torque noise.

    uv run python benchmarks/noise_sources.py [--family one] [--seeds 1 2 3] [--friction KIND]

On the tuning plant family (one, seeds 1-3; issue #19 item 5), for each seed: identify the
Omni's model on 120 s of free motion (:func:`~teleop_force.reports.accuracy.
identify_free_motion`), then estimate 60 s of teleoperation touching a soft floor with
several estimators, each fed

- the recorded angles and torques (what any estimator gets),
- the plant's *true* angles instead of the encoder counts (no quantization),
- the *applied* torques instead of the commanded ones (no actuator noise),

and print the contact error, its lag and bias parts and the false force in free motion
(:func:`~teleop_force.reports.accuracy.accuracy_figures`). The true signals are a diagnosis:
no estimator has them.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from teleop_force.estimation.batch import BatchEstimator
from teleop_force.estimation.estimator import with_estimator
from teleop_force.reports.accuracy import (
    TEST_SEED_OFFSET,
    CascadeReference,
    accuracy_figures,
    identify_free_motion,
    plant_config,
)
from teleop_force.simulation.families import PlantFamily
from teleop_force.simulation.floor_touch import floor_touch_protocol

#: The estimators compared: observer bandwidth [Hz], pre-filter cutoff [Hz] and stages.
ESTIMATORS: dict[str, tuple[float, float, int]] = {
    "observer 24 Hz on one stage at 20 Hz (L_v)": (24.0, 20.0, 1),
    "observer 40 Hz on one stage at 40 Hz": (40.0, 40.0, 1),
    "observer 40 Hz on two stages at 40 Hz (the Omni's)": (40.0, 40.0, 2),
}
#: Which signals replace the recorded ones.
INPUTS = ("recorded", "true angles", "applied torques", "true angles and applied torques")


def main() -> None:
    """Print the contact error of every estimator on every input variant."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", default="one", choices=("one", "two"))
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--friction", default=None, help="friction kind (default: the Omni's)")
    args = parser.parse_args()
    family = PlantFamily.parse(args.family)
    table: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for seed in args.seeds:
        model, _ = identify_free_motion(family, seed, friction=args.friction)
        test = floor_touch_protocol(
            60.0, seed + TEST_SEED_OFFSET, family=family, plant_config=plant_config(family, seed)
        )
        for name, (observer_hz, prefilter_hz, stages) in ESTIMATORS.items():
            chosen = with_estimator(
                model, "observer", observer_hz, observer_prefilter_hz=prefilter_hz,
                observer_prefilter_stages=stages,
            )  # fmt: skip
            config = chosen.filter_config
            reference = CascadeReference(config)(test.f_tip_in_base_n, test.sample_interval_s)
            estimator = BatchEstimator(chosen)
            for inputs in INPUTS:
                q = test.q_true_rad if "angles" in inputs else test.q_rad
                tau = test.tau_applied_nm if "torques" in inputs else test.tau_nm
                force = estimator.estimate(test.t_s, q, tau).force_tip_in_base_n
                figures = accuracy_figures(test, force, reference, config.warmup_s)
                table.setdefault((name, inputs), []).append(figures)
    seeds = " / ".join(map(str, args.seeds))
    print(f"family {family.value}, seeds {seeds} ({args.friction or 'default friction'})")
    print(
        "| estimator | inputs | error in contact [%] | lag [N] | bias [N] | false force, free [N] |"
    )
    print("|---|---|---|---|---|---|")
    for (name, inputs), rows in table.items():
        per_seed = " / ".join(f"{r['contact_error_pct']:.2f}" for r in rows)
        lag, bias, free = (
            np.mean([r[k] for r in rows]) for k in ("lag_n", "bias_n", "free_false_force_n")
        )
        print(f"| {name} | {inputs} | {per_seed} | {lag:.3f} | {bias:.3f} | {free:.3f} |")


if __name__ == "__main__":
    main()
