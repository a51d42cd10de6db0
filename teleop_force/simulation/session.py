"""Simulated recording sessions: the PID-controlled :class:`SimulatedOmni` following a reference.

:func:`simulate_session` runs the control loop at 1 kHz through the
:class:`~teleop_force.robots.device.Device` interface (read, PID, command, step) and returns a
:class:`SimulatedSession` of arrays: what a real recording holds (time, measured angles,
commanded torques, ground-truth tip force) plus the simulator's truth for tests (true state,
reference, applied torque, true friction and effects torques).

Protocol builders follow the paper's section IV: :func:`rigid_body_protocol` (IV-A),
:func:`friction_protocol` (IV-B experiments 1-2), :func:`teleoperation_protocol` (experiment 3)
and :func:`palpation_protocol` (contact with a soft tissue, for force estimation).

Seeds: a session's ``seed`` feeds both the trajectory (where it is random) and, through
:class:`numpy.random.SeedSequence`, the plant's actuator noise; the same seed gives the same
arrays, bit for bit.

Families: every function takes ``family=`` (:class:`~teleop_force.simulation.families.PlantFamily`,
default ``ONE``, the :class:`SimulatedOmni`, unchanged). ``family=PlantFamily.TWO`` runs
:class:`~teleop_force.simulation.plant_two.SimulatedOmniTwo`: ``plant_config`` is then a
:class:`~teleop_force.simulation.plant_two.PlantTwoConfig` (default: the arm of instance
``seed``; pass one to keep the arm and vary the session's seed), the default surface of
:func:`palpation_protocol` is a :class:`~teleop_force.simulation.floor_contact.HuntCrossleyFloor`,
and the true friction is recorded tick by tick (LuGre has a state). ``tip_mass_kg`` adds a
payload at the tip on either family (:mod:`~teleop_force.simulation.payload`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from time import perf_counter
from typing import TypedDict, Unpack

import numpy as np

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.robots import omni
from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.effects import PlantEffect, total_effect_torque
from teleop_force.simulation.families import PlantFamily, default_contact, make_plant
from teleop_force.simulation.floor_contact import HuntCrossleyFloor
from teleop_force.simulation.lugre_friction import LuGreFriction
from teleop_force.simulation.payload import check_tip_mass, with_tip_payload
from teleop_force.simulation.pid import PID, PIDGains
from teleop_force.simulation.plant import PlantConfig, SimulatedOmni
from teleop_force.simulation.plant_two import PlantTwoConfig, SimulatedOmniTwo
from teleop_force.simulation.trajectories import (
    Trajectory,
    friction_trajectory,
    palpation_trajectory,
    rigid_body_trajectory,
    slow_stretch_trajectory,
    teleoperation_trajectory,
)
from teleop_force.simulation.true_friction import TrueFriction

_ARRAY_FIELDS = (
    "q_rad",
    "tau_nm",
    "f_tip_in_base_n",
    "q_true_rad",
    "qd_true_rad_s",
    "q_ref_rad",
    "qd_ref_rad_s",
    "tau_applied_nm",
    "tau_friction_true_nm",
    "tau_effects_true_nm",
)


@dataclass(frozen=True, eq=False)
class SimulatedSession:
    """One simulated recording, N samples at the control rate (arrays are read-only).

    Row ``k`` holds the state at ``t_s[k]`` and the torque commanded from it, which acts from
    ``t_s[k]`` to ``t_s[k+1]``.

    Attributes:
        t_s: Sample times (N,).
        q_rad: Measured (quantized) angles (N, 3).
        tau_nm: Commanded motor torques, clipped (N, 3).
        f_tip_in_base_n: True force of the tip on the environment, base frame (N, 3).
        q_true_rad: True angles (N, 3).
        qd_true_rad_s: True velocities (N, 3).
        q_ref_rad: Reference angles (N, 3).
        qd_ref_rad_s: Reference velocities (N, 3).
        tau_applied_nm: Torque that acted on the plant: commanded plus actuator noise (N, 3).
        tau_friction_true_nm: True friction torque at the true velocities (N, 3); family two:
            the LuGre torque at the sample's state.
        tau_effects_true_nm: Sum of the switched-on effects' torques (N, 3).
        seed: The session's seed.
        name: Protocol name (``rigid-body``, ``friction-equal``...), or ``custom``.
        friction: The plant's true friction (``None``: frictionless).
        effects: The plant's switched-on effects.
        contact: The tissue (family two: the floor), or ``None``.
        clipped_ticks: Number of ticks in which a torque command was clipped.
        wall_time_s: How long the simulation took.
        family: The plant family (``"one"`` or ``"two"``).
        tip_mass_kg: The payload at the tip [kg].

    """

    t_s: np.ndarray
    q_rad: np.ndarray
    tau_nm: np.ndarray
    f_tip_in_base_n: np.ndarray
    q_true_rad: np.ndarray
    qd_true_rad_s: np.ndarray
    q_ref_rad: np.ndarray
    qd_ref_rad_s: np.ndarray
    tau_applied_nm: np.ndarray
    tau_friction_true_nm: np.ndarray
    tau_effects_true_nm: np.ndarray
    seed: int
    name: str = "custom"
    friction: TrueFriction | LuGreFriction | None = None
    effects: tuple[PlantEffect, ...] = field(default_factory=tuple)
    contact: PlaneContact | HuntCrossleyFloor | None = None
    clipped_ticks: int = 0
    wall_time_s: float = 0.0
    family: str = PlantFamily.ONE.value
    tip_mass_kg: float = 0.0

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=float)
        if t.ndim != 1 or t.size < 1:
            raise DataError(f"t_s must be a non-empty vector, got shape {t.shape}")
        t.flags.writeable = False
        object.__setattr__(self, "t_s", t)
        for name in _ARRAY_FIELDS:
            value = np.array(getattr(self, name), dtype=float)
            if value.shape != (t.size, 3):
                raise DataError(f"{name} must have shape ({t.size}, 3), got {value.shape}")
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        object.__setattr__(self, "effects", tuple(self.effects))

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t_s.size)

    @property
    def duration_s(self) -> float:
        """Time span covered, ``N * dt``."""
        return float(self.t_s[-1] - self.t_s[0]) + self.sample_interval_s

    @property
    def sample_interval_s(self) -> float:
        """Control period (median sample interval; 0 for one sample)."""
        return float(np.median(np.diff(self.t_s))) if self.t_s.size > 1 else 0.0

    def tracking_error_rad(self) -> np.ndarray:
        """``q_ref - q_true`` (N, 3)."""
        return self.q_ref_rad - self.q_true_rad

    def tracking_rms_rad(self, skip_s: float = 0.0) -> np.ndarray:
        """Per-joint RMS tracking error, ignoring the first ``skip_s`` seconds (3,)."""
        keep = self.t_s >= self.t_s[0] + skip_s
        return np.sqrt(np.mean(self.tracking_error_rad()[keep] ** 2, axis=0))

    def interchange_columns(self, with_force: bool = True) -> dict[str, np.ndarray]:
        """Return the columns ``t, q1..q3, tau1..tau3[, f_*]`` of docs/interchange_csv.md."""
        columns: dict[str, np.ndarray] = {"t": self.t_s}
        columns.update({f"q{j + 1}": self.q_rad[:, j] for j in range(3)})
        columns.update({f"tau{j + 1}": self.tau_nm[:, j] for j in range(3)})
        if with_force:
            columns.update({f"f_{a}": self.f_tip_in_base_n[:, j] for j, a in enumerate("xyz")})
        return columns


def simulate_session(
    trajectory: Trajectory,
    duration_s: float,
    seed: int = 0,
    *,
    effects: Sequence[PlantEffect] = (),
    contact: PlaneContact | HuntCrossleyFloor | None = None,
    plant_config: PlantConfig | PlantTwoConfig | None = None,
    pid_gains: PIDGains | None = None,
    name: str = "custom",
    family: PlantFamily | str = PlantFamily.ONE,
    tip_mass_kg: float = 0.0,
) -> SimulatedSession:
    """Run the PID-controlled plant along ``trajectory`` for ``duration_s`` at the control rate.

    The plant starts at rest at the reference's start, and the PID's integral is preset to the
    true holding torque there (a bumpless start). ``family`` and ``tip_mass_kg``: see the
    module docstring.
    """
    if not (math.isfinite(duration_s) and duration_s > 0.0):
        raise ConfigurationError(f"duration_s must be > 0, got {duration_s}")
    if trajectory.n_joints != 3:
        raise ConfigurationError(
            f"the simulated Omni has 3 joints, trajectory has {trajectory.n_joints}"
        )
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigurationError(f"seed must be an integer >= 0, got {seed!r}")
    family = PlantFamily.parse(family)
    tip_mass_kg = check_tip_mass(tip_mass_kg)
    if family is PlantFamily.TWO:
        return _simulate_family_two(
            trajectory,
            duration_s,
            int(seed),
            effects=effects,
            contact=contact,
            plant_config=plant_config,
            pid_gains=pid_gains,
            name=name,
            tip_mass_kg=tip_mass_kg,
        )
    if plant_config is not None and not isinstance(plant_config, PlantConfig):
        raise ConfigurationError("plant family one takes a PlantConfig")
    if contact is not None and not isinstance(contact, PlaneContact):
        raise ConfigurationError("plant family one takes a PlaneContact")
    config = plant_config if plant_config is not None else PlantConfig()
    gains = pid_gains if pid_gains is not None else PIDGains.omni()
    dt = config.control_period_s
    n = max(1, round(duration_s / dt))
    t = np.arange(n) * dt
    q_ref, qd_ref = trajectory.sample(t)

    started = perf_counter()
    plant = SimulatedOmni(
        config,
        seed=np.random.SeedSequence(int(seed)).spawn(1)[0],
        effects=effects,
        contact=contact,
        q0_rad=q_ref[0],
        qd0_rad_s=qd_ref[0],
        description=(
            with_tip_payload(omni.omni_description(), tip_mass_kg) if tip_mass_kg > 0.0 else None
        ),
    )
    pid = PID(gains, n_joints=3, control_period_s=dt)
    pid.reset(integral_nm=plant.holding_torque_nm())
    arrays = {name_: np.empty((n, 3)) for name_ in _ARRAY_FIELDS}
    q_meas, tau_cmd, force = arrays["q_rad"], arrays["tau_nm"], arrays["f_tip_in_base_n"]
    q_true, qd_true, tau_applied = (
        arrays["q_true_rad"],
        arrays["qd_true_rad_s"],
        arrays["tau_applied_nm"],
    )
    with plant:
        for k in range(n):
            state = plant.read()
            command = plant.command_torque(pid.update(q_ref[k], state.q_rad, qd_ref[k]))
            q_meas[k] = state.q_rad
            tau_cmd[k] = command.tau_nm
            force[k] = state.f_tip_in_base_n
            q_true[k] = plant.q_true_rad
            qd_true[k] = plant.qd_true_rad_s
            plant.step()
            tau_applied[k] = plant.tau_applied_nm
        clipped = plant.clip_count
    arrays["q_ref_rad"] = q_ref
    arrays["qd_ref_rad_s"] = qd_ref
    friction = config.friction
    arrays["tau_friction_true_nm"] = (
        np.zeros((n, 3)) if friction is None else friction.torque(qd_true)
    )
    arrays["tau_effects_true_nm"] = total_effect_torque(
        tuple(effects), t, q_true, qd_true, tau_applied
    )
    return SimulatedSession(
        t_s=t,
        seed=int(seed),
        name=name,
        friction=friction,
        effects=tuple(effects),
        contact=contact,
        clipped_ticks=clipped,
        wall_time_s=perf_counter() - started,
        family=PlantFamily.ONE.value,
        tip_mass_kg=tip_mass_kg,
        **arrays,
    )


def _simulate_family_two(
    trajectory: Trajectory,
    duration_s: float,
    seed: int,
    *,
    effects: Sequence[PlantEffect],
    contact: PlaneContact | HuntCrossleyFloor | None,
    plant_config: PlantConfig | PlantTwoConfig | None,
    pid_gains: PIDGains | None,
    name: str,
    tip_mass_kg: float,
) -> SimulatedSession:
    """:func:`simulate_session` on plant family two (same loop; friction recorded per tick)."""
    if plant_config is not None and not isinstance(plant_config, PlantTwoConfig):
        raise ConfigurationError("plant family two takes a PlantTwoConfig")
    config = plant_config if plant_config is not None else PlantTwoConfig(instance_seed=seed)
    gains = pid_gains if pid_gains is not None else PIDGains.omni()
    dt = config.control_period_s
    n = max(1, round(duration_s / dt))
    t = np.arange(n) * dt
    q_ref, qd_ref = trajectory.sample(t)

    started = perf_counter()
    plant = make_plant(
        PlantFamily.TWO,
        seed=np.random.SeedSequence(seed).spawn(1)[0],
        effects=effects,
        contact=contact,
        tip_mass_kg=tip_mass_kg,
        config=config,
        q0_rad=q_ref[0],
        qd0_rad_s=qd_ref[0],
    )
    if not isinstance(plant, SimulatedOmniTwo):  # pragma: no cover - make_plant's contract
        raise ConfigurationError("make_plant(TWO) did not return a SimulatedOmniTwo")
    pid = PID(gains, n_joints=3, control_period_s=dt)
    pid.reset(integral_nm=plant.holding_torque_nm())
    arrays = {name_: np.empty((n, 3)) for name_ in _ARRAY_FIELDS}
    q_meas, tau_cmd, force = arrays["q_rad"], arrays["tau_nm"], arrays["f_tip_in_base_n"]
    q_true, qd_true = arrays["q_true_rad"], arrays["qd_true_rad_s"]
    tau_applied, friction = arrays["tau_applied_nm"], arrays["tau_friction_true_nm"]
    with plant:
        for k in range(n):
            state = plant.read()
            command = plant.command_torque(pid.update(q_ref[k], state.q_rad, qd_ref[k]))
            q_meas[k] = state.q_rad
            tau_cmd[k] = command.tau_nm
            force[k] = state.f_tip_in_base_n
            q_true[k] = plant.q_true_rad
            qd_true[k] = plant.qd_true_rad_s
            friction[k] = plant.friction_torque_nm()
            plant.step()
            tau_applied[k] = plant.tau_applied_nm
        clipped = plant.clip_count
    arrays["q_ref_rad"] = q_ref
    arrays["qd_ref_rad_s"] = qd_ref
    arrays["tau_effects_true_nm"] = total_effect_torque(
        tuple(effects), t, q_true, qd_true, tau_applied
    )
    return SimulatedSession(
        t_s=t,
        seed=seed,
        name=name,
        friction=plant.true_friction,
        effects=tuple(effects),
        contact=plant.contact,
        clipped_ticks=clipped,
        wall_time_s=perf_counter() - started,
        family=PlantFamily.TWO.value,
        tip_mass_kg=plant.config.tip_mass_kg,
        **arrays,
    )


class SessionOptions(TypedDict, total=False):
    """What every protocol passes on to :func:`simulate_session` (its docstring says each)."""

    effects: Sequence[PlantEffect]
    plant_config: PlantConfig | PlantTwoConfig | None
    pid_gains: PIDGains | None
    family: PlantFamily | str
    tip_mass_kg: float


def rigid_body_protocol(
    duration_s: float = 240.0, seed: int = 0, **options: Unpack[SessionOptions]
) -> SimulatedSession:
    """Paper IV-A: 4 minutes of 4 sinusoids per joint at 0.5-2 Hz.

    See :func:`~teleop_force.simulation.trajectories.rigid_body_trajectory`; ``options``
    (:class:`SessionOptions`) go to :func:`simulate_session`.
    """
    return simulate_session(
        rigid_body_trajectory(seed), duration_s, seed, name="rigid-body", **options
    )


def friction_protocol(
    mode: str, duration_s: float = 240.0, seed: int = 0, **options: Unpack[SessionOptions]
) -> SimulatedSession:
    """Paper IV-B experiments 1-2: slow sinusoids (<= 0.7 Hz), joints 2-3 moving ``mode``.

    ``mode`` is ``"equal"``, ``"opposite"`` or ``"independent"`` (see
    :func:`~teleop_force.simulation.trajectories.friction_trajectory`).
    """
    return simulate_session(
        friction_trajectory(mode, seed), duration_s, seed, name=f"friction-{mode}", **options
    )


def teleoperation_protocol(
    duration_s: float = 60.0, seed: int = 0, **options: Unpack[SessionOptions]
) -> SimulatedSession:
    """Paper IV-B experiment 3: band-limited random motion (an operator moving the master)."""
    return simulate_session(
        teleoperation_trajectory(seed), duration_s, seed, name="teleoperation", **options
    )


def slow_stretch_protocol(
    duration_s: float = 120.0,
    seed: int = 0,
    *,
    slow_fraction: float = 0.4,
    **options: Unpack[SessionOptions],
) -> SimulatedSession:
    """Free band-limited random motion with slow stretches (``slow_fraction`` of the time).

    See :func:`~teleop_force.simulation.trajectories.slow_stretch_trajectory`: the
    teleoperation protocol's motion, partly played 5-50 times slower, so an identification
    also sees the low joint speeds that touching a surface lives at. No contact.
    """
    return simulate_session(
        slow_stretch_trajectory(duration_s, seed, slow_fraction=slow_fraction),
        duration_s,
        seed,
        name="slow-stretch",
        **options,
    )


def palpation_protocol(
    duration_s: float = 30.0,
    seed: int = 0,
    *,
    surface_y_m: float = -0.06,
    depth_m: float = 0.006,
    contact: PlaneContact | HuntCrossleyFloor | None = None,
    **options: Unpack[SessionOptions],
) -> SimulatedSession:
    """Palpation of a soft tissue: approach, press ``depth_m`` into it, slide, release; repeat.

    ``contact`` defaults to a horizontal :class:`PlaneContact` at ``y = surface_y_m``
    (300 N/m: the PID's integral drives the tip to the reference depth, ~1.8 N at 6 mm);
    on family two to a :class:`HuntCrossleyFloor` there (~1.5 N at 6 mm, 3200 N/m^1.5).
    """
    family = options.get("family", PlantFamily.ONE)
    tissue = contact if contact is not None else default_contact(family, surface_y_m)
    trajectory = palpation_trajectory(duration_s, seed, surface_y_m=surface_y_m, depth_m=depth_m)
    return simulate_session(
        trajectory, duration_s, seed, contact=tissue, name="palpation", **options
    )
