"""The estimator's per-sample cost in a plain loop: ``step`` and ``update`` against ``pin.rnea``.

    uv run python benchmarks/step_loop.py MODEL.json [--seconds 12] [--samples 8000]

Streams a simulated palpation (``bench.data.palpation_arrays``) through
:class:`~teleop_force.estimation.estimator.ForceEstimator`, timing each call with
``perf_counter_ns`` (the first 500 left out), then times ``pin.rnea`` on the equivalent rigid
body. Prints the p50 and p99 of ``step`` (the service's call) and ``update`` [µs], and one
``rnea`` [µs]. Runs unchanged on older trees (``PYTHONPATH`` on a worktree) for before/after.
"""

from __future__ import annotations

import argparse
import gc
import time

import numpy as np
import pinocchio as pin

from teleop_force.bench.data import palpation_arrays
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.identification.dynamic_model import DynamicModel


def main() -> None:
    """Time ``step``, ``update`` and ``rnea``; print them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model")
    parser.add_argument("--seconds", type=float, default=12.0)
    parser.add_argument("--samples", type=int, default=8000)
    args = parser.parse_args()
    model = DynamicModel.load(args.model)
    palpation = palpation_arrays(args.seconds, 0)
    t, q, tau = palpation["t_s"], palpation["q_rad"], palpation["tau_nm"]
    estimator = ForceEstimator(model)
    n = min(args.samples, t.size)
    rows = [(float(t[k]), np.array(q[k]), np.array(tau[k])) for k in range(n)]

    def run(call):  # type: ignore[no-untyped-def]
        estimator.reset()
        ns = np.empty(n)
        clock = time.perf_counter_ns
        for k in range(n):
            a, b, c = rows[k]
            start = clock()
            call(a, b, c)
            ns[k] = clock() - start
        return np.percentile(ns[500:], [50, 99]) / 1e3

    gc.collect()
    gc.disable()
    for name, call in (("step", estimator.step), ("update", estimator.update)):
        run(call)  # warm
        p50, p99 = run(call)
        print(f"{name}: p50 {p50:.2f} us, p99 {p99:.2f} us")
    robot = estimator.robot
    if robot is not None:
        pin_model, data = robot.model, robot.model.createData()
        angles = robot.to_model(q[100])
        zero, velocity = np.zeros(pin_model.nv), np.full(pin_model.nv, 0.3)
        start = time.perf_counter_ns()
        for _ in range(20000):
            pin.rnea(pin_model, data, angles, velocity, zero)
        print(f"rnea: {(time.perf_counter_ns() - start) / 20000 / 1e3:.3f} us")


if __name__ == "__main__":
    main()
