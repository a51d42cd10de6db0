"""Close the loop: find what a model lacks in a recording, name it, add it, report.

The recording is a simulated Omni session with an effect the model does not have planted in
the plant: cogging of motor 1, a torque periodic in ``q1``. The residual loop is told nothing;
it fits the model, traces what is left to a joint, a variable and a kind of effect, adds it,
and reports the error before and after on time blocks held out from every fit. The same loop
runs on files with ``teleop-force residual DATA --json``.

Expect the cogging first (joint 1, ``q1``, position-periodic). The loop may then also name
Stribeck friction on some joints: the simulator's true friction has that shape and the
coupled Coulomb-viscous model fitted here does not, so those findings are real too.

Run: ``uv run python examples/03_close_the_loop.py [--effect cogging] [--seconds 20]``
(15 to 50 s; other effects: ``position-friction``, ``elbow-bump``, ``load-friction``...).
"""

from __future__ import annotations

import argparse

import teleop_force as tf
from teleop_force.residual.options import ResidualOptions
from teleop_force.simulation import EFFECT_NAMES, make_effect, rigid_body_protocol


def main() -> None:
    """Plant an effect, run the loop, print what it found."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effect", choices=EFFECT_NAMES, default="cogging")
    parser.add_argument("--seconds", type=float, default=20.0, help="session length [s]")
    args = parser.parse_args()

    session = rigid_body_protocol(args.seconds, seed=5, effects=[make_effect(args.effect)])
    recording = tf.Recording(session.t_s, session.q_rad, session.tau_nm)

    # Coupled Coulomb-viscous friction (the CLI's default for the Omni is the wavelet network;
    # the coupled CV keeps this example fast).
    options = ResidualOptions(friction="coupled-cv")
    report = tf.trace_residual([recording], tf.omni_description(), options)

    print(f"planted: {args.effect}")
    for j, (before, after) in enumerate(zip(report.before, report.after, strict=True)):
        print(f"joint {j + 1}: held-out relative RMS {before:.1%} -> {after:.1%}")
    for effect in report.to_json()["effects"]:
        print(
            f"found: {effect['description']} ({effect['kind']}, depends on "
            f"{', '.join(effect['depends_on'])}), explains {effect['explained']:.0%} "
            f"of joint {effect['joint']}'s residual"
        )
    if not report.effects:
        print("found nothing significant")


if __name__ == "__main__":
    main()
