"""The candidate effects the residual loop tries on each joint.

Candidates are linear in their parameters (:mod:`teleop_force.identification.effects`): smooth
or periodic functions of any joint angle or angle difference (optionally direction-modulated:
position dependent friction), of other joints' velocities (coupling), of the motor torque
(load dependent friction), of time (drift), Stribeck-like low-speed shapes and offsets.
"""

from __future__ import annotations

import numpy as np

from teleop_force.identification.effects import BasisSpec, variable_values
from teleop_force.residual.options import ResidualOptions
from teleop_force.residual.samples import SelectedSamples


def candidate_effects(
    samples: SelectedSamples,
    joint: int,
    n: int,
    residual: np.ndarray,
    options: ResidualOptions,
    has_offsets: bool,
    velocity_covered: tuple[int, ...] = (),
) -> list[BasisSpec]:
    """List candidate effects for one joint, given its current ``residual`` at the samples.

    ``velocity_covered``: velocities the friction already maps.
    """
    return (
        _pose_candidates(samples, joint, n, residual, options)
        + _coupling_candidates(samples, joint, n, velocity_covered)
        + _fixed_candidates(joint, has_offsets, velocity_covered)
    )


def _pose_candidates(
    samples: SelectedSamples,
    joint: int,
    n: int,
    residual: np.ndarray,
    options: ResidualOptions,
) -> list[BasisSpec]:
    """Smooth (plain and direction-modulated) and periodic functions of angles and differences."""
    specs: list[BasisSpec] = []
    names = [f"q{i + 1}" for i in range(n)] + [
        f"q{a + 1}-q{b + 1}" for a in range(n) for b in range(a + 1, n)
    ]
    selected = samples.stacked_rows
    for name in names:
        x = variable_values(name, samples.t_s, samples.q_rad, samples.qd_rad_s, samples.load_nm)
        lo, hi = np.percentile(x, [0.5, 99.5])
        if hi - lo < 1e-3:
            continue
        for count in options.smooth_counts:
            specs.append(BasisSpec(joint, name, "smooth", "none", float(lo), float(hi), count))
        for count in options.modulated_counts:
            specs.append(BasisSpec(joint, name, "smooth", "sign", float(lo), float(hi), count))
            specs.append(BasisSpec(joint, name, "smooth", "both", float(lo), float(hi), count))
        frequency = dominant_frequency(x[selected], residual, float(hi - lo))
        if frequency is not None:
            specs.append(
                BasisSpec(
                    joint,
                    name,
                    "periodic",
                    "none",
                    frequency=frequency,
                    harmonics=options.harmonics,
                )
            )
    return specs


def _coupling_candidates(
    samples: SelectedSamples, joint: int, n: int, velocity_covered: tuple[int, ...]
) -> list[BasisSpec]:
    """Smooth functions of the other joints' velocities the friction does not map."""
    specs = []
    for k in range(n):
        if k == joint or k in velocity_covered:
            continue
        x = samples.qd_rad_s[:, k]
        lo, hi = np.percentile(x, [0.5, 99.5])
        if hi - lo > 1e-3:
            specs.append(BasisSpec(joint, f"qd{k + 1}", "smooth", "none", float(lo), float(hi), 6))
    return specs


def _fixed_candidates(
    joint: int, has_offsets: bool, velocity_covered: tuple[int, ...]
) -> list[BasisSpec]:
    """Load-dependent friction, drift, low-speed friction and offsets."""
    specs = []
    if not has_offsets:
        # The load is the rigid-body model torque (see teleop_force.identification.effects):
        # robots with a model.
        specs.append(BasisSpec(joint, f"tau{joint + 1}", "abs", "sign"))
    specs.append(BasisSpec(joint, "t", "linear", "none"))
    specs.append(BasisSpec(joint, "t", "linear", "sign"))
    if joint not in velocity_covered:
        specs.append(
            BasisSpec(joint, f"qd{joint + 1}", "stribeck", "sign", scales=(0.03, 0.1, 0.3))
        )
    if not has_offsets:
        specs.append(BasisSpec(joint, "t", "constant", "none"))
    specs.append(BasisSpec(joint, "t", "constant", "positive"))
    return specs


def dominant_frequency(x: np.ndarray, residual: np.ndarray, span: float) -> float | None:
    """Spatial frequency of the strongest periodic component of ``residual`` over ``x``."""
    if span <= 0:
        return None
    low = 2.0 * np.pi * 2.0 / span
    grid = np.linspace(max(low, 2.0), 120.0, 600)
    if grid.size == 0:
        return None
    r = residual - residual.mean()
    phase = np.outer(x, grid)
    power = (r @ np.cos(phase)) ** 2 + (r @ np.sin(phase)) ** 2
    return float(grid[int(np.argmax(power))])


def friction_change_candidates(joint: int) -> list[BasisSpec]:
    """List changes of the joint's own friction against a model in hand: viscous, Coulomb.

    Offered only when the model's friction is kept fixed
    (:mod:`teleop_force.residual.from_model`): warmer motors or a worn cable change the
    friction the model knows, and that change is itself the effect to name.
    """
    return [
        BasisSpec(joint, f"qd{joint + 1}", "linear", "none"),
        BasisSpec(joint, "t", "constant", "sign"),
    ]


def is_friction_shaped(spec: BasisSpec) -> bool:
    """Return whether ``spec`` is a function of its own joint's velocity alone (friction)."""
    own = spec.variable == f"qd{spec.joint + 1}"
    return own or (spec.shape == "constant" and spec.modulation == "sign")
