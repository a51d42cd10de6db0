"""The estimate's residual in free motion, per joint and model, on simulated palpations.

    uv run python benchmarks/free_residual.py MODEL.json [MODEL.json ...] [--seeds 2 4]
        [--seconds 200]

For each seed, one palpation of the project's simulated Omni (``palpation_protocol``, the
demo's script: free motion between touches of a soft floor) goes through each model's batch
estimator. Prints, per model, the RMS and the mean of the external-torque estimate over the
samples without contact (true force zero, after 5 s) [mN m]: what the residual watch looks
at. Written to compare the shipped model (the network alone) with the same protocol's model
on the coupled CV (issue #19, docs/results.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from teleop_force.estimation.batch import BatchEstimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.simulation import palpation_protocol


def main() -> None:
    """Print the free-motion residual of every model on every seed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", type=Path)
    parser.add_argument("--seeds", nargs="+", type=int, default=[2, 4])
    parser.add_argument("--seconds", type=float, default=200.0)
    args = parser.parse_args()
    models = {path: DynamicModel.load(path) for path in args.models}
    for seed in args.seeds:
        session = palpation_protocol(args.seconds, seed)
        t = np.asarray(session.t_s)
        free = (np.linalg.norm(session.f_tip_in_base_n, axis=1) == 0.0) & (t > t[0] + 5.0)
        for path, model in models.items():
            estimate = BatchEstimator(model).estimate(t, session.q_rad, session.tau_nm)
            residual = 1e3 * estimate.tau_external_nm[free]
            rms = np.sqrt(np.mean(residual**2, axis=0))
            mean = residual.mean(axis=0)
            print(
                f"seed {seed} {path.name}: free {free.mean():.2f} of the samples,"
                f" RMS {np.array2string(rms, precision=2)} mN m,"
                f" mean {np.array2string(mean, precision=2)} mN m"
            )


if __name__ == "__main__":
    main()
