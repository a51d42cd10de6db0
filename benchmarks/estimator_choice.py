"""How the default estimator, its bandwidth and the standstill dead band were chosen.

    uv run python benchmarks/estimator_choice.py [--family one] [--seeds 1 2 3] [--json]
        [--identify-protocol teleoperation|slow-stretch] [--friction KIND]

For each seed of the *tuning* plant family (family one, seeds 1-3: issue #19 item 5), a model
is identified on 120 s of free motion and every candidate estimator runs over the same 60 s of
teleoperation touching a soft floor (:mod:`teleop_force.reports.accuracy`, which
``teleop-force accuracy`` runs with one estimator). Prints the candidates ranked by the mean
contact-force error, with the false force in free motion and the error at rest in contact.
The defaults of :class:`~teleop_force.identification.filtered_regressor.FilterConfig` are the
best of this table; plant family two (seeds 4-6) is only ever *reported* with them.
``--identify-protocol`` and ``--friction`` change what the model is identified on and with
(:class:`~teleop_force.reports.accuracy.AccuracyOptions`), for choices of the excitation and
the friction made on the same tuning set.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from typing import Any

from teleop_force.reports.accuracy import (
    DEFAULT_IDENTIFY_PROTOCOL,
    IDENTIFY_PROTOCOLS,
    TEST_SEED_OFFSET,
    BatchEstimate,
    CascadeReference,
    accuracy_figures,
    identify_free_motion,
    plant_config,
)
from teleop_force.simulation.families import PlantFamily
from teleop_force.simulation.floor_touch import floor_touch_protocol

#: The observer on ``L_v`` (one stage at ``velocity_cutoff_hz``): what it ran on before it had
#: a pre-filter of its own, spelled out since models identified now carry two 40 Hz stages.
_ON_LV: dict[str, Any] = {"observer_prefilter_hz": None, "observer_prefilter_stages": 1}

#: The candidates: filter overrides of the identified model's FilterConfig.
CANDIDATES: tuple[dict[str, Any], ...] = (
    {"estimator": "filter", "standstill_band_rad_s": 0.0},
    {"estimator": "filter", "cutoff_hz": 16.0, "standstill_band_rad_s": 0.0},
    {"estimator": "filter", "cutoff_hz": 24.0, "standstill_band_rad_s": 0.0},
    {"estimator": "filter", "cutoff_hz": 16.0, "velocity_cutoff_hz": 40.0},
    *(
        {"estimator": "observer", "observer_hz": hz, "standstill_band_rad_s": 0.0, **_ON_LV}
        for hz in (8.0, 16.0, 20.0, 24.0, 28.0, 32.0, 48.0)
    ),
    {"estimator": "observer", "observer_hz": 24.0, "velocity_cutoff_hz": 40.0, **_ON_LV},
    {"estimator": "observer", "observer_hz": 20.0, "velocity_cutoff_hz": 30.0, **_ON_LV},
    {"estimator": "observer", "observer_hz": 28.0, "velocity_cutoff_hz": 15.0, **_ON_LV},
    *(
        {"estimator": "observer", "observer_hz": 24.0, "standstill_band_rad_s": band, **_ON_LV}
        for band in (0.01, 0.02, 0.05)
    ),
    # the observer on its own pre-filter (issue #19, fifth session): one stage at L_v's 20 Hz
    # (what the observer ran on before), two stages in cascade at 30-50 Hz
    {
        "estimator": "observer",
        "observer_hz": 24.0,
        "observer_prefilter_hz": 20.0,
        "observer_prefilter_stages": 1,
    },
    *(
        {
            "estimator": "observer",
            "observer_hz": hz,
            "observer_prefilter_hz": pre,
            "observer_prefilter_stages": 2,
        }
        for hz, pre in (
            (30.0, 40.0),
            (40.0, 40.0),
            (50.0, 40.0),
            (35.0, 35.0),
            (40.0, 45.0),
            (50.0, 50.0),
            (40.0, 30.0),
        )
    ),
    *(
        {
            "estimator": "observer",
            "observer_hz": 40.0,
            "observer_prefilter_hz": 40.0,
            "observer_prefilter_stages": 2,
            "standstill_band_rad_s": band,
        }
        for band in (0.0, 0.01, 0.04)
    ),
)


def main() -> None:
    """Run every candidate on every seed; print the ranking (or JSON)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", default="one", choices=("one", "two"))
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--json", action="store_true", help="print every figure as JSON")
    parser.add_argument(
        "--identify-protocol", choices=list(IDENTIFY_PROTOCOLS), default=DEFAULT_IDENTIFY_PROTOCOL
    )
    parser.add_argument("--friction", default=None, help="friction kind (default: the Omni's)")
    args = parser.parse_args()
    family = PlantFamily.parse(args.family)
    rows = []
    for seed in args.seeds:
        model, _ = identify_free_motion(
            family, seed, protocol=args.identify_protocol, friction=args.friction
        )
        test = floor_touch_protocol(
            60.0, seed + TEST_SEED_OFFSET, family=family, plant_config=plant_config(family, seed)
        )
        for overrides in CANDIDATES:
            estimate = BatchEstimate(overrides)
            force = estimate(model, test)
            reference = CascadeReference(estimate.config(model))(
                test.f_tip_in_base_n, test.sample_interval_s
            )
            figures = accuracy_figures(test, force, reference, model.filter_config.warmup_s)
            rows.append({"seed": seed, "overrides": overrides, **figures})
    if args.json:
        print(json.dumps(rows, default=float))
        return
    by_candidate: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_candidate[json.dumps(row["overrides"])].append(row)

    def mean(items: list[dict[str, Any]], key: str) -> float:
        return sum(float(r[key]) for r in items) / len(items)

    print(
        f"family {family.value}, seeds {' '.join(map(str, args.seeds))},"
        f" identified on {args.identify_protocol} ({args.friction or 'default friction'})"
    )
    print("| error in contact [%] | false force, free [N] | error at rest [N] | candidate |")
    print("|---|---|---|---|")
    ranked = sorted(by_candidate.items(), key=lambda kv: mean(kv[1], "contact_error_pct"))
    for key, items in ranked:
        print(
            f"| {mean(items, 'contact_error_pct'):.2f} | {mean(items, 'free_false_force_n'):.3f}"
            f" | {mean(items, 'rest_contact_error_n'):.3f} | {key} |"
        )


if __name__ == "__main__":
    main()
