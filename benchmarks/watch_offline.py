"""The residual watch offline: first report after a planted effect, false reports, evaluation cost.

The streams are made by ``master_slave.watched_streams.watched_session``, as
the demo makes them: the simulated Omni under the PID along the palpation script, the
service's estimator on each sample, the wire payloads packed as the slave and the service pack
them, appended to the watch's ring and evaluated every second of stream time, the watch
testing its own estimate (``WatchResidual``, as in the service). Per seed:

- ``clean``: 600 s without an effect; every report is false;
- each effect (``position-friction``, ``load-friction``, ``drifting-friction``): switched on at
  60 s with the demo's calibration (``scale`` x the joint's RMS commanded torque), run to 100 s;
  a report before the switch or on another joint than the effect's is false.

Usage::

    uv run python benchmarks/watch_offline.py [--seeds 1,2,3] [--scale 0.1] [--json]

Prints one line per seed and case: the first report after the switch [s] (``none``), the
finding (joint, variable, effect fraction), the false reports, and the evaluation's time per
call (mean / max, ms). ``--json`` prints one JSON object per line instead.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from master_slave.slave import EffectSwitch
from master_slave.watched_streams import watched_session
from teleop_force.service.residual_watch import WatchConfig, append_cost_ns

EFFECTS = ("position-friction", "load-friction", "drifting-friction")
CLEAN_S = 600.0
EFFECT_AT_S = 60.0
EFFECT_RUN_S = 100.0


def run_case(seed: int, effect: str | None, scale: float, config: WatchConfig) -> dict[str, object]:
    """Simulate one session and run the watch on it; return its figures."""
    duration_s = CLEAN_S if effect is None else EFFECT_RUN_S
    switch = None if effect is None else EffectSwitch(effect, at_s=EFFECT_AT_S, scale=scale)
    session = watched_session(duration_s, seed, switch, config)
    first_after: float | None = None
    finding = None
    false_reports = []
    for joint, at_s, variable, fraction in session.reports:
        right = joint == session.effect_joint and at_s >= EFFECT_AT_S
        if right and first_after is None:
            first_after = round(at_s - EFFECT_AT_S, 1)
            finding = (joint, variable, round(fraction, 3))
        elif not right:
            false_reports.append((joint, round(at_s, 1), variable, round(fraction, 3)))
    costs_ms = np.asarray(session.evaluation_ms)
    return {
        "seed": seed,
        "case": effect or "clean",
        "effect": session.effect,
        "first_report_after_switch_s": first_after,
        "finding": finding,
        "false_reports": false_reports,
        "evaluation_ms_mean": round(float(np.mean(costs_ms)), 2),
        "evaluation_ms_max": round(float(np.max(costs_ms)), 2),
    }


def main() -> None:
    """Run every seed and case; print one line (or JSON object) each."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--scale", type=float, default=0.1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    config = WatchConfig()
    print(f"# {config}")
    print(f"# append_cost_ns {append_cost_ns():.0f}")
    for seed in (int(s) for s in args.seeds.split(",")):
        for effect in (*EFFECTS, None):
            row = run_case(seed, effect, args.scale, config)
            if args.json:
                print(json.dumps(row), flush=True)
                continue
            first = row["first_report_after_switch_s"]
            target = (
                ""
                if effect is None
                else (" ok" if first is not None and first <= 30.0 else " MISS")
            )
            print(
                f"seed {seed} {row['case']:18s} first report after switch: "
                f"{'none' if first is None else f'{first:.1f} s'}{target} {row['finding'] or ''} "
                f"false: {row['false_reports'] or 0} "
                f"eval ms mean/max {row['evaluation_ms_mean']}/{row['evaluation_ms_max']}",
                flush=True,
            )


if __name__ == "__main__":
    main()
