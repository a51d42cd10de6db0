"""Benchmark (not a test): the slave's per-tick plant work and offline simulation speed.

Per tick, as ``master_slave/slave.py``'s control loop does: ``plant.read()``, ``pid.update``,
``plant.command_torque``, the floats it publishes, ``plant.step()``, on the demo's plant (no
effects) palpating the demo's tissue; median and 99th percentile over ``--ticks`` ticks after a
warm-up. Offline: ``palpation_protocol`` and ``rigid_body_protocol`` wall time per tick.

Each measurement runs in a fresh process; with ``--before DIR`` (a tree holding an older
``teleop_force``, e.g. ``git archive 07e5ec7 teleop_force | tar -x -C DIR``) the old and the
current code run alternately, round after round, so both see the same machine load::

    uv run python -m tests.simulation.bench_plant_tick --before /tmp/before --rounds 5

Prints one JSON object: per code, the median over rounds of each figure.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

_WORKER = r"""
import json, sys, time
import numpy as np
import teleop_force
from teleop_force.simulation import (
    PID, PIDGains, PlaneContact, PlantConfig, SimulatedOmni, palpation_protocol,
    palpation_trajectory, rigid_body_protocol,
)
from teleop_force.simulation.trajectories import omni_inverse_kinematics

n_ticks, warm = int(sys.argv[1]), 2000
surface = -0.06
start = omni_inverse_kinematics(np.array([0.0, surface + 0.02, 0.12]))
reference = palpation_trajectory((n_ticks + warm) * 1e-3 + 10.0, 0, surface_y_m=surface)
q_refs, _ = reference.sample(np.arange(n_ticks + warm) * 1e-3)
plant = SimulatedOmni(
    PlantConfig(), seed=0, contact=PlaneContact.horizontal(surface), q0_rad=start
)
pid = PID(PIDGains.omni(), n_joints=3, control_period_s=1e-3)
pid.reset(integral_nm=plant.holding_torque_nm())
times = np.empty(n_ticks + warm)
contact = 0
clock = time.perf_counter_ns
for k in range(n_ticks + warm):
    q_ref = q_refs[k]
    started = clock()
    state = plant.read()
    q = state.q_rad
    tau = pid.update(q_ref, q)
    command = plant.command_torque(tau)
    published = (
        tuple(q.tolist()), tuple(pid.velocity_rad_s.tolist()), tuple(command.tau_nm.tolist()),
        tuple(state.f_tip_in_base_n.tolist()),
    )
    plant.step()
    times[k] = (clock() - started) * 1e-3
    contact += published[3][1] != 0.0
ticks = times[warm:]
out = {
    "tick_median_us": float(np.median(ticks)),
    "tick_p99_us": float(np.percentile(ticks, 99)),
    "tick_mean_us": float(np.mean(ticks)),
    "contact_fraction": contact / (n_ticks + warm),
}
for name, run in (
    ("palpation_protocol_us_per_tick", lambda: palpation_protocol(duration_s=20.0, seed=1)),
    ("rigid_body_protocol_us_per_tick", lambda: rigid_body_protocol(duration_s=20.0, seed=1)),
):
    started = time.perf_counter()
    session = run()
    out[name] = (time.perf_counter() - started) / session.n_samples * 1e6
out["code"] = str(teleop_force.__file__)
print(json.dumps(out))
"""


def _measure(tree: Path | None, n_ticks: int) -> dict[str, float | str]:
    env = dict(os.environ)
    if tree is not None:  # the old tree first on the path, and as the working directory
        env["PYTHONPATH"] = str(tree)
    result = subprocess.run(
        [sys.executable, "-c", _WORKER, str(n_ticks)],
        cwd=tree if tree is not None else Path(__file__).resolve().parents[2],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    """Run the rounds and print the medians as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, help="tree holding the old teleop_force")
    parser.add_argument("--ticks", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    variants: dict[str, Path | None] = {"current": None}
    if args.before is not None:
        variants = {"before": args.before, "current": None}
    rounds: dict[str, list[dict[str, float | str]]] = {name: [] for name in variants}
    for _ in range(args.rounds):
        for name, tree in variants.items():
            rounds[name].append(_measure(tree, args.ticks))
    summary: dict[str, dict[str, float | str]] = {}
    for name, results in rounds.items():
        figures: dict[str, float | str] = {"code": results[0]["code"], "rounds": len(results)}
        for key, value in results[0].items():
            if isinstance(value, float):
                values = [float(r[key]) for r in results]
                figures[key] = round(statistics.median(values), 2)
        summary[name] = figures
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
