"""Seeded closed-loop runs of the simulated Omni, shared by the tests and the fixture writer.

Each case drives a plant with the PID along a palpation reference through the ``Device``
interface, exactly as ``simulate_session`` and the slave do (read, PID, command, step), and
returns per-tick arrays. ``plant_fixture.npz`` holds every ``FIXTURE_STRIDE``-th row of each case
as computed by the plant before it was compiled (git 07e5ec7, the same simulation code as
c6e3135); rewrite it only on purpose::

    uv run python -m tests.simulation.plant_cases tests/simulation/plant_fixture.npz
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from teleop_force.simulation import (
    EFFECT_NAMES,
    PID,
    PIDGains,
    PlaneContact,
    PlantConfig,
    PlantEffect,
    SimulatedOmni,
    TrueFriction,
    make_effect,
    palpation_trajectory,
)
from teleop_force.simulation.effects import ElbowAngleBump

FIXTURE_STRIDE = 15
FIELDS = ("q_true", "qd_true", "force", "q_measured", "tau_command", "tau_applied")
#: The fields kept in the fixture (the others follow from them).
FIXTURE_FIELDS = ("q_true", "qd_true", "force", "tau_command")


@dataclass(frozen=True)
class WobbleEffect(PlantEffect):
    """An effect the compiled plant does not know (its Python path): ``A sin(q1) qd_j``."""

    name: ClassVar[str] = "wobble"
    amplitude_nms_per_rad: float = 0.004

    def joint_torque(self, t_s: Any, q_rad: Any, qd_rad_s: Any, tau_motor_nm: Any) -> Any:
        """Return ``A sin(q1) qd_j``."""
        return self.amplitude_nms_per_rad * np.sin(q_rad[..., 0]) * qd_rad_s[..., self.joint]

    def velocity_slope(self, t_s: Any, q_rad: Any, qd_rad_s: Any, tau_motor_nm: Any) -> Any:
        """Return ``A sin(q1)``."""
        return self.amplitude_nms_per_rad * np.sin(q_rad[..., 0])


def _all_effects(bump_centre_rad: float) -> list[PlantEffect]:
    effects = [make_effect(name) for name in EFFECT_NAMES if name != "elbow-bump"]
    return [*effects, ElbowAngleBump(joint=2, centre_rad=bump_centre_rad)]


@dataclass(frozen=True)
class PlantCase:
    """One seeded run: plant settings, contact, effects and length."""

    name: str
    n_ticks: int
    config: Callable[[], PlantConfig]
    contact: Callable[[], PlaneContact | None]
    effects: Callable[[], list[PlantEffect]]
    seed: int = 3


CASES = (
    # The demo's plant (no effects), in contact with a tissue from the first tick.
    PlantCase("demo", 3000, PlantConfig, lambda: PlaneContact.horizontal(-0.039), list),
    # Every built-in effect, the coupled friction made stronger, approach then palpation; the
    # motion (q2 - q3 in 0.55-0.64) runs on the elbow bump's flank.
    PlantCase(
        "effects",
        4500,
        lambda: PlantConfig(friction=TrueFriction(interaction_gain=0.6).scaled(1.5)),
        lambda: PlaneContact.tilted(-0.06, 0.15, damping_s_per_m=8.0),
        lambda: _all_effects(0.3),
    ),
    # The same with the bump centred on the motion: this run amplifies a change of 1e-15 rad
    # in its start to ~1e-7 rad after 3 s (so does the plant before compilation), so it
    # matches to 1e-12 only for its first ~2.5 s.
    PlantCase(
        "sensitive",
        4500,
        lambda: PlantConfig(friction=TrueFriction(interaction_gain=0.6).scaled(1.5)),
        lambda: PlaneContact.tilted(-0.06, 0.15, damping_s_per_m=8.0),
        lambda: _all_effects(0.6),
    ),
    # No friction, noise or quantisation; 3 sub-steps, no gravity.
    PlantCase(
        "ideal",
        2000,
        lambda: PlantConfig(substeps=3, gravity=False).ideal(),
        lambda: PlaneContact.horizontal(-0.039),
        list,
    ),
    # An effect of a class the kernels do not know, beside built-in ones (the Python path);
    # a low torque limit clips commands.
    PlantCase(
        "custom-effect",
        1500,
        lambda: PlantConfig(torque_limit_nm=0.03),
        lambda: PlaneContact.horizontal(-0.039),
        lambda: [WobbleEffect(joint=1), make_effect("load-friction"), make_effect("cogging")],
    ),
)


def run_case(case: PlantCase, plant_type: Callable[..., Any] = SimulatedOmni) -> dict[str, Any]:
    """Run ``case`` on a plant built by ``plant_type`` (default :class:`SimulatedOmni`)."""
    reference = palpation_trajectory(case.n_ticks * 1e-3 + 10.0, case.seed)
    q_ref, qd_ref = reference.sample(np.arange(case.n_ticks) * 1e-3)
    config = case.config()
    plant = plant_type(
        config,
        seed=np.random.SeedSequence(case.seed).spawn(1)[0],
        effects=case.effects(),
        contact=case.contact(),
        q0_rad=q_ref[0],
    )
    pid = PID(PIDGains.omni(), n_joints=3, control_period_s=config.control_period_s)
    pid.reset(integral_nm=plant.holding_torque_nm())
    out = {name: np.empty((case.n_ticks, 3)) for name in FIELDS}
    for k in range(case.n_ticks):
        state = plant.read()
        command = plant.command_torque(pid.update(q_ref[k], state.q_rad, qd_ref[k]))
        out["q_measured"][k] = state.q_rad
        out["force"][k] = state.f_tip_in_base_n
        out["tau_command"][k] = command.tau_nm
        out["q_true"][k] = plant.q_true_rad
        out["qd_true"][k] = plant.qd_true_rad_s
        plant.step()
        out["tau_applied"][k] = plant.tau_applied_nm
    return {**out, "clip_count": plant.clip_count, "t_s": plant.t_s}


def write_fixture(path: str) -> None:
    """Write every ``FIXTURE_STRIDE``-th row of every case to ``path`` (.npz)."""
    arrays: dict[str, np.ndarray] = {}
    for case in CASES:
        result = run_case(case)
        for name in FIXTURE_FIELDS:
            arrays[f"{case.name}/{name}"] = result[name][::FIXTURE_STRIDE]
        arrays[f"{case.name}/clip_count"] = np.array(result["clip_count"])
    np.savez_compressed(path, **arrays)


if __name__ == "__main__":
    write_fixture(sys.argv[1])
