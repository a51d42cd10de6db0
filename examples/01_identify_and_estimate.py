"""Identify a model from a recording, then estimate contact forces sample by sample.

Two simulated Omni sessions stand in for recordings of the real arm: the paper's rigid-body
protocol (free motion, to identify from) and a palpation of soft tissue (contact, with the
simulator's true force to compare with). With real data, read the files instead:
``tf.read_recording("my_session.csv")`` (interchange CSV or ``.mcap``).

Run: ``uv run python examples/01_identify_and_estimate.py [--seconds 30]`` (about 15 s).
"""

from __future__ import annotations

import argparse

import numpy as np

import teleop_force as tf
from teleop_force.simulation import palpation_protocol, rigid_body_protocol


def main() -> None:
    """Identify, estimate, compare with the true force."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="identification session [s]")
    args = parser.parse_args()

    # 1. A recording: time, joint angles and commanded motor torques (no force sensor).
    free = rigid_body_protocol(args.seconds, seed=1)
    training = tf.Recording(free.t_s, free.q_rad, free.tau_nm)

    # 2. Identify rigid body + friction (what `teleop-force identify --friction coupled-cv` does).
    model, report = tf.identify_model([training], tf.omni_description(), "coupled-cv")
    print("training relative RMS per joint:", np.round(report.friction_relative_rms, 3))

    # 3. Estimate the tip force, one 1 kHz sample at a time, as the live service does.
    touch = palpation_protocol(10.0, seed=2)
    estimator = tf.ForceEstimator(model)
    force_n = np.array(
        [
            estimator.update(t, q, tau).force_tip_in_base_n
            for t, q, tau in zip(touch.t_s, touch.q_rad, touch.tau_nm, strict=True)
        ]
    )

    # 4. Compare with the simulator's true force while in contact (|F| > 0.1 N).
    true_n = touch.f_tip_in_base_n
    contact = np.linalg.norm(true_n, axis=1) > 0.1
    error_rms = np.sqrt(np.nanmean((force_n[contact] - true_n[contact]) ** 2, axis=0))
    true_rms = np.sqrt(np.mean(true_n[contact] ** 2, axis=0))
    print(f"{contact.sum()} samples in contact")
    for axis, err, ref in zip("xyz", error_rms, true_rms, strict=True):
        print(f"f_{axis}: RMS error {err:.3f} N (true force RMS {ref:.3f} N)")


if __name__ == "__main__":
    main()
