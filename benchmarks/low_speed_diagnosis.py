"""Where the held-out contact-force error lives, and what a better friction could still gain.

    uv run python benchmarks/low_speed_diagnosis.py [--seeds 1 2 3] [--identify-protocol ...]
        [--observer-hz HZ --observer-prefilter-hz HZ --observer-prefilter-stages N]

The estimator flags (:mod:`teleop_force.estimation.flags`) replace the identified model's
estimator, as ``teleop-force accuracy`` takes them.

On plant family one (the tuning family of issue #19; family two is held out and is not
diagnosed here), for each seed: identify the Omni's default model on 120 s of free motion
(:func:`~teleop_force.reports.accuracy.identify_free_motion`), estimate 60 s of teleoperation
touching a soft floor with the default estimator, and print

1. the share of the squared contact error (and of its bias part, against the true force
   filtered like the estimate) on samples where joint 2, or every joint, is slower than 0.01
   and 0.05 rad/s;
2. per joint and per band of the joint's *true* speed, in contact: the fraction of samples,
   the RMS joint-torque bias ``tau_ext_hat - J^T F_ref`` and the mean model-minus-true
   friction (times ``sgn(qd)``, the dead band applied), and the network's coverage trust;
3. the fraction of time each joint spends below 0.01/0.02/0.05/0.1 rad/s in the
   identification motion and in contact;
4. the figures of :mod:`~teleop_force.reports.accuracy` with the model's friction replaced
   by: its coupled-CV fallback alone; the plant's *true* friction at the estimator's velocity
   (what any friction function of the measured motion can reach at best); the true friction
   at the true velocity (not realisable: a ceiling); the model's friction with the last
   sliding value held at rest instead of the dead band. The estimator's momentum observer is
   linear in the friction torque, so each variant is the default estimate plus the
   observer's response to the friction difference (reproduces the full estimator: the
   ``model`` row equals ``teleop-force accuracy``).

Uses the batch estimator's internals (``_prefilter``, ``_observer_loop``): a diagnosis,
not an API.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from teleop_force.estimation.batch import (
    BatchEstimator,
    _observer_loop,
    _prefilter,
    _start_mask,
    output_filter_loop,
)
from teleop_force.estimation.estimator import estimator_from_args
from teleop_force.estimation.flags import add_estimator_arguments
from teleop_force.friction.terms import standstill_factors
from teleop_force.reports.accuracy import (
    DEFAULT_IDENTIFY_PROTOCOL,
    IDENTIFY_PROTOCOLS,
    TEST_SEED_OFFSET,
    CascadeReference,
    accuracy_figures,
    identify_free_motion,
    plant_config,
)
from teleop_force.simulation.families import PlantFamily
from teleop_force.simulation.floor_touch import floor_touch_protocol

SPEED_EDGES = (0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, np.inf)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def _held_at_rest(friction: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """Return the friction, its last value where every joint moved held through the dead band.

    A sticking Coulomb term (as the test stand's): ``factor f + (1 - factor) f_last``, with
    ``f_last`` the friction at the last sample whose standstill factor was 1.
    """
    out = np.empty_like(friction)
    last = np.zeros(friction.shape[1])
    for k in range(friction.shape[0]):
        if factor[k] >= 1.0:
            last = friction[k]
        out[k] = factor[k] * friction[k] + (1.0 - factor[k]) * last
    return out


def main() -> None:
    """Print the diagnosis of every seed, then the friction variants' mean figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    add_estimator_arguments(parser)
    parser.add_argument(
        "--identify-protocol", choices=list(IDENTIFY_PROTOCOLS), default=DEFAULT_IDENTIFY_PROTOCOL
    )
    args = parser.parse_args()
    family = PlantFamily.ONE
    table: dict[str, list[dict[str, float]]] = {}
    for seed in args.seeds:
        model, ident = identify_free_motion(family, seed, protocol=args.identify_protocol)
        model = estimator_from_args(model, args)
        test = floor_touch_protocol(
            60.0, seed + TEST_SEED_OFFSET, family=family, plant_config=plant_config(family, seed)
        )
        config = model.filter_config
        estimator = BatchEstimator(model)
        estimates = estimator.estimate(test.t_s, test.q_rad, test.tau_nm)
        force = test.f_tip_in_base_n
        reference = CascadeReference(config)(force, test.sample_interval_s)
        keep = test.t_s >= test.t_s[0] + config.warmup_s
        contact = keep & (np.linalg.norm(force, axis=1) > 0.0)
        qd_true = np.ascontiguousarray(test.qd_true_rad_s)
        jacobian = estimator._jacobians(test.q_rad)
        assert jacobian is not None
        tau_ref = np.einsum("kij,ki->kj", jacobian, reference)  # J^T F_ref
        bias_tau = estimates.tau_external_nm - tau_ref
        figures = accuracy_figures(test, estimates.force_tip_in_base_n, reference, config.warmup_s)
        print(
            f"== family one, seed {seed}: contact error {figures['contact_error_pct']:.2f} %"
            f" (lag {figures['lag_n']:.3f} N, bias {figures['bias_n']:.3f} N)"
        )
        error2 = np.sum((estimates.force_tip_in_base_n - force) ** 2, axis=1)
        bias2 = np.sum((estimates.force_tip_in_base_n - reference) ** 2, axis=1)
        for name, speed in (
            ("|qd2|", np.abs(qd_true[:, 1])),
            ("every |qd_j|", np.max(np.abs(qd_true), axis=1)),
        ):
            for limit in (0.01, 0.05):
                low = contact & (speed < limit)
                print(
                    f"  {name} < {limit}: {low.sum() / contact.sum():.2f} of contact samples,"
                    f" {error2[low].sum() / error2[contact].sum():.2f} of the squared error,"
                    f" {bias2[low].sum() / bias2[contact].sum():.2f} of the squared bias"
                )
        print("  median |qd| in contact:", np.round(np.median(np.abs(qd_true[contact]), axis=0), 4))
        band = config.standstill_band_rad_s
        friction = model.friction_torque(qd_true) * standstill_factors(qd_true, band)[:, None]
        assert test.friction is not None
        friction_error = friction - test.friction.torque(qd_true)
        trust = model.friction.coverage_weight(qd_true)
        print(
            "  true speed band [rad/s] | contact fraction j1 j2 j3 | torque bias RMS [mN m]"
            " | model - true friction, x sgn(qd) [mN m] | trust"
        )
        for lo, hi in itertools.pairwise(SPEED_EDGES):
            cells: list[list[float]] = [[], [], [], []]
            for j in range(3):
                rows = contact & (np.abs(qd_true[:, j]) >= lo) & (np.abs(qd_true[:, j]) < hi)
                signed = friction_error[rows, j] * np.sign(qd_true[rows, j])
                cells[0].append(rows.sum() / contact.sum())
                cells[1].append(1e3 * _rms(bias_tau[rows, j]))
                cells[2].append(1e3 * float(np.mean(signed)) if rows.any() else np.nan)
                cells[3].append(float(np.mean(trust[rows, j])) if rows.any() else np.nan)
            print(
                f"  [{lo:.3f}, {hi:.3f}) | "
                + " | ".join(" ".join(f"{x:6.2f}" for x in cell) for cell in cells)
            )
        for name, qd in (("identification", ident.qd_true_rad_s), ("contact", qd_true[contact])):
            fractions = [
                [round(float(np.mean(np.abs(qd[:, j]) < v)), 3) for v in (0.01, 0.02, 0.05, 0.1)]
                for j in range(3)
            ]
            print(f"  time below 0.01/0.02/0.05/0.1 rad/s, {name}, per joint: {fractions}")
        # friction variants by the observer's linearity in the friction torque
        t = np.ascontiguousarray(test.t_s)
        starts = _start_mask(t.size, None)
        q = np.ascontiguousarray(test.q_rad)
        prefilter_hz, stages = config.estimator_prefilter
        _, _, qd, dt = _prefilter(
            t, q, np.ascontiguousarray(test.tau_nm), starts, 2 * np.pi * prefilter_hz, stages
        )
        used = model.friction_torque(qd) * standstill_factors(qd, band)[:, None]
        fallback = model.friction.fallback
        true_friction = test.friction
        variants = {
            "the model's friction (the estimate itself)": used,
            "coupled-CV fallback alone": fallback.torque(qd)
            * standstill_factors(qd, band)[:, None],
            "true friction at the estimated velocity": (
                true_friction.torque(qd) * standstill_factors(qd, band)[:, None]
            ),
            "true friction at the true velocity (ceiling)": true_friction.torque(qd_true),
            "sticking: the last sliding friction held at rest": _held_at_rest(
                model.friction_torque(qd), standstill_factors(qd, band)
            ),
        }
        for name, torque in variants.items():
            delta = np.ascontiguousarray(torque - used)
            zero = np.zeros_like(delta)
            change = _observer_loop(
                zero, zero, zero, delta, dt, starts, 2 * np.pi * config.observer_hz,
                int(config.torque_lag_samples),
            )  # fmt: skip
            if config.estimator_output_hz > 0.0:  # linear too
                output_filter_loop(change, dt, starts, 2 * np.pi * config.estimator_output_hz)
            tip, _ = estimator._tip_forces(jacobian, estimates.tau_external_nm + change)
            table.setdefault(name, []).append(
                accuracy_figures(test, tip, reference, config.warmup_s)  # type: ignore[arg-type]
            )
    print(f"\nfamily one, seeds {' '.join(map(str, args.seeds))} ({args.identify_protocol})")
    print(
        "| friction in the estimate | error in contact [%] | false force, free [N]"
        " | error at rest [N] | bias [N] |"
    )
    print("|---|---|---|---|---|")
    for name, rows in table.items():
        per_seed = " / ".join(f"{r['contact_error_pct']:.2f}" for r in rows)
        free = np.mean([r["free_false_force_n"] for r in rows])
        rest = " / ".join(f"{r['rest_contact_error_n']:.3f}" for r in rows)
        bias = np.mean([r["bias_n"] for r in rows])
        print(f"| {name} | {per_seed} | {free:.3f} | {rest} | {bias:.3f} |")


if __name__ == "__main__":
    main()
