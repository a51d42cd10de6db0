"""The simulated PHANTOM Omni behind the :class:`~teleop_force.robots.device.Device` interface.

Dynamics in motor coordinates (docs/conventions.md), with every effect on the left-hand side::

    M(q) qdd + C(q, qd) qd + N(q) + k (q2 - pi/2) + tau_f(qd) + tau_effects + J^T F = tau + w

``tau`` is the clipped commanded torque, held over the control tick (zero-order hold), ``w``
Gaussian actuator noise drawn once per tick, ``tau_f`` the :class:`TrueFriction`, ``F`` the
force of the tip on the tissue (:class:`PlaneContact`) and ``tau_effects`` the switched-on
:mod:`~teleop_force.simulation.effects`.

Integration: each 1 ms tick is split into ``substeps`` (default 4, 0.25 ms) semi-implicit Euler
steps ``qd += h qdd; q += h qd``. Per tick, pinocchio evaluates ``M``, ``C qd + N``, the tip
Jacobian ``J`` and the tip position ``p0`` once, at the tick's start state (one
``computeAllTerms`` call); within the tick the tip moves as ``p0 + J (q - q0)`` and the spring,
friction, contact and effects are re-evaluated at every sub-step. Friction is stiff (the
smoothed sign has slope ~5 N m s/rad against inertias down to 6e-4 kg m^2: a time constant of
~0.1 ms), so it is integrated *linearly implicitly*: each sub-step solves
``(M + h D) qdd = rhs`` with ``D = d(tau_f + tau_effects)/d qd``, stable for any sub-step.
The sub-steps are for accuracy: against 16 sub-steps, 4 leave ~1e-4 N m RMS of torque error
and < 1e-4 rad of angle error on the friction and palpation protocols (below the actuator
noise and the encoder count; 2 sub-steps double these, 1 quadruples them), and the contact
(300 N/m, ~25 Hz at the joints) is resolved with 160 steps per period. With no torque,
friction or gravity, the mechanical energy drifts by ~0.3 % over 1 s.

Measured angles are quantized to the encoder resolution. All randomness (actuator noise) comes
from one seeded :class:`numpy.random.Generator`, so a run is reproducible.

Speed: the state lives in one float workspace; a tick is one compiled call
(:mod:`~teleop_force.simulation.plant_kernels`), one ``computeAllTerms`` and one compiled
refresh, so ``read``, ``command_torque`` and ``step`` cost a few microseconds each. Effects of
classes the kernels do not know (subclasses, custom :class:`PlantEffect`) switch the plant to a
Python integrator with the same formulas.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from teleop_force.errors import ConfigurationError, DataError, ModelError
from teleop_force.robots import omni
from teleop_force.robots.description import Robot, RobotDescription
from teleop_force.robots.device import Device, DeviceReading, TorqueCommand
from teleop_force.simulation import plant_kernels as kernels
from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.effects import PlantEffect, checked_effects
from teleop_force.simulation.true_friction import TrueFriction

_NOISE_BLOCK_TICKS = 4096


@dataclass(frozen=True)
class PlantConfig:
    """Physical and numerical settings of :class:`SimulatedOmni`.

    Attributes:
        control_period_s: One control tick (what :meth:`SimulatedOmni.step` advances).
        substeps: Integration sub-steps per tick (>= 1).
        torque_limit_nm: Symmetric motor torque limit.
        torque_noise_std_nm: Standard deviation of the actuator noise added to the torque.
        encoder_resolution_rad: Quantization step of the measured angles (0: exact).
        spring_stiffness_nm_per_rad: Stiffness of the gravity-compensation spring(s).
        gravity: Whether gravity acts (off for energy checks).
        friction: The true friction, or ``None`` for a frictionless plant.

    """

    control_period_s: float = 1e-3
    substeps: int = 4
    torque_limit_nm: float = omni.MOTOR_TORQUE_LIMIT_NM
    torque_noise_std_nm: float = 2e-3
    encoder_resolution_rad: float = omni.ENCODER_RESOLUTION_RAD
    spring_stiffness_nm_per_rad: float = omni.SPRING_STIFFNESS_NM_PER_RAD
    gravity: bool = True
    friction: TrueFriction | None = field(default_factory=TrueFriction)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.control_period_s) and self.control_period_s > 0.0):
            raise ConfigurationError(f"control_period_s must be > 0, got {self.control_period_s}")
        if not isinstance(self.substeps, int) or self.substeps < 1:
            raise ConfigurationError(f"substeps must be an integer >= 1, got {self.substeps}")
        if not (math.isfinite(self.torque_limit_nm) and self.torque_limit_nm > 0.0):
            raise ConfigurationError(f"torque_limit_nm must be > 0, got {self.torque_limit_nm}")
        for name in (
            "torque_noise_std_nm",
            "encoder_resolution_rad",
            "spring_stiffness_nm_per_rad",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")

    def ideal(self) -> PlantConfig:
        """Return a copy without friction, noise and quantization (gravity and spring kept)."""
        return dataclasses.replace(
            self, friction=None, torque_noise_std_nm=0.0, encoder_resolution_rad=0.0
        )


class _RigidBodyTerms:
    """Per-tick evaluation of ``M``, ``C qd + N``, ``J`` and ``p`` in motor coordinates.

    Same numbers as :class:`Robot`'s methods (tested), with one ``computeAllTerms`` call; the
    coupling to motor coordinates is :func:`~teleop_force.simulation.plant_kernels.refresh_terms`.
    """

    def __init__(self, robot: Robot) -> None:
        self.model = robot.model
        self.data = robot.model.createData()
        self.coupling = robot.coupling
        self.rotor = np.asarray(robot.description.rotor_inertia_kgm2, dtype=float)
        tip = robot.description.tip_frame
        if tip is None:
            raise ModelError(f"{robot.description.name}: the plant needs a tip frame")
        self.tip = self.model.getFrameId(tip)
        self.fills_both_triangles = self._check_fills_both_triangles(robot.n)
        # pinocchio hands out views of its data: kept once when they stay valid (they do in
        # the releases we know), else fetched every tick.
        self._mass_view, self._bias_view, self._tip_view = first = self._views()
        self._views_persist = all(
            np.shares_memory(a, b) for a, b in zip(first, self._views(), strict=True)
        )

    def _check_fills_both_triangles(self, n: int) -> bool:
        # Older pinocchio releases fill only the upper triangle of M; newer ones both.
        self.data.M[:] = np.nan
        q = np.linspace(0.1, 0.3, n)
        pin.computeAllTerms(self.model, self.data, q, q)
        return bool(np.allclose(self.data.M, self.data.M.T))

    def _views(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.data.M, self.data.nle, self.data.oMf[self.tip].translation

    def refresh(
        self,
        ws: np.ndarray,
        q_model: np.ndarray,
        qd_model: np.ndarray,
        constants: np.ndarray,
        contact: np.ndarray,
    ) -> None:
        """Evaluate pinocchio at ``(q_model, qd_model)`` (views of ``ws``); refresh ``ws``."""
        model, data, tip = self.model, self.data, self.tip
        pin.computeAllTerms(model, data, q_model, qd_model)
        pin.updateFramePlacement(model, data, tip)
        jacobian = pin.getFrameJacobian(model, data, tip, pin.LOCAL_WORLD_ALIGNED)
        if self._views_persist:
            mass, bias, position = self._mass_view, self._bias_view, self._tip_view
        else:
            mass, bias, position = self._views()
        kernels.refresh_terms(ws, constants, contact, mass, bias, jacobian, position)

    def evaluate(
        self, q: np.ndarray, qd: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(M, C qd + N, J, p)`` at motor angles ``q`` and velocities ``qd``."""
        ws = np.zeros(kernels.WORKSPACE_SIZE)
        ws[kernels.Q : kernels.Q + 3] = q
        ws[kernels.QD : kernels.QD + 3] = qd
        constants = _constants(PlantConfig(), self, ())
        kernels.to_model_coordinates(ws, constants)
        q_model = ws[kernels.Q_MODEL : kernels.Q_MODEL + 3]
        qd_model = ws[kernels.QD_MODEL : kernels.QD_MODEL + 3]
        self.refresh(ws, q_model, qd_model, constants, np.zeros(0))
        return (
            ws[kernels.MASS : kernels.MASS + 9].reshape(3, 3).copy(),
            ws[kernels.BIAS : kernels.BIAS + 3].copy(),
            ws[kernels.JACOBIAN : kernels.JACOBIAN + 9].reshape(3, 3).copy(),
            ws[kernels.TIP : kernels.TIP + 3].copy(),
        )


def _constants(
    config: PlantConfig, terms: _RigidBodyTerms, springs: Sequence[tuple[int, float, float]]
) -> np.ndarray:
    """Pack the plant's constants in the layout of :mod:`~teleop_force.simulation.plant_kernels`."""
    constants = np.zeros(kernels.CONSTANTS_SIZE)
    constants[kernels.SUBSTEP_S] = config.control_period_s / config.substeps
    constants[kernels.SUBSTEPS] = config.substeps
    constants[kernels.PERIOD_S] = config.control_period_s
    constants[kernels.RESOLUTION_RAD] = config.encoder_resolution_rad
    for joint, rest_angle, stiffness in springs:
        if constants[kernels.SPRINGS + 2 * joint] != 0.0:
            raise ModelError(f"two springs on joint {joint + 1} are not supported")
        constants[kernels.SPRINGS + 2 * joint] = stiffness
        constants[kernels.SPRINGS + 2 * joint + 1] = rest_angle
    constants[kernels.FILLS_BOTH_TRIANGLES] = float(terms.fills_both_triangles)
    constants[kernels.COUPLING : kernels.COUPLING + 9] = np.asarray(terms.coupling).ravel()
    constants[kernels.ROTOR : kernels.ROTOR + 3] = terms.rotor
    return constants


def _reading(t_s: float, values: np.ndarray) -> DeviceReading:
    """Build a :class:`DeviceReading` from 9 finite floats (angles, torques, force), unchecked.

    The hot path of :meth:`SimulatedOmni.read`: the value the validating constructor builds
    (read-only float 3-vectors, here views of one immutable copy, and a float time; tested) at
    a sixth of its cost.
    """
    frozen = np.frombuffer(values.tobytes())  # read-only: backed by bytes
    reading = DeviceReading.__new__(DeviceReading)
    vars(reading).update(
        t_s=t_s, q_rad=frozen[0:3], tau_nm=frozen[3:6], f_tip_in_base_n=frozen[6:9]
    )
    return reading


def _torque_command(tau_nm: np.ndarray, clipped: np.ndarray) -> TorqueCommand:
    """Build a :class:`TorqueCommand` without its dataclass ``__init__`` (hot path)."""
    command = TorqueCommand.__new__(TorqueCommand)
    vars(command).update(tau_nm=tau_nm, clipped=clipped)
    return command


class SimulatedOmni(Device):
    """The simulated 3-joint Omni (dynamics and integration in the module docstring).

    ``read()`` returns the quantized angles, the last commanded torque and the true contact
    force (zeros without contact). The true state, friction and effects are exposed for tests.
    """

    def __init__(
        self,
        config: PlantConfig | None = None,
        *,
        seed: int | np.random.SeedSequence | None = 0,
        effects: Sequence[PlantEffect] = (),
        contact: PlaneContact | None = None,
        q0_rad: np.ndarray | None = None,
        qd0_rad_s: np.ndarray | None = None,
        description: RobotDescription | None = None,
    ) -> None:
        """Create the plant at ``q0_rad`` (default: mid-range) with ``qd0_rad_s`` (default 0).

        ``seed`` seeds the actuator noise; ``description`` defaults to the built-in Omni.
        """
        self.config = config if config is not None else PlantConfig()
        super().__init__(self.config.torque_limit_nm)
        description = description if description is not None else omni.omni_description()
        if description.n_joints != 3 or description.model is None:
            raise ModelError("SimulatedOmni needs a 3-joint description with a rigid-body model")
        if not self.config.gravity:
            model = description.model.copy()
            model.gravity = pin.Motion.Zero()
            description = dataclasses.replace(description, model=model)
        self.description = description
        self.robot = Robot(description)
        self._terms = _RigidBodyTerms(self.robot)
        self._springs = tuple(
            (s.joint, s.rest_angle_rad, self.config.spring_stiffness_nm_per_rad)
            for s in description.springs
        )
        self._constants = _constants(self.config, self._terms, self._springs)
        self._limit = np.broadcast_to(self._torque_limit_nm, (3,)).copy()
        # The whole state, in the layout of plant_kernels; the attributes below are views.
        self._ws = np.zeros(kernels.WORKSPACE_SIZE)
        ws = self._ws
        self._q = ws[kernels.Q : kernels.Q + 3]
        self._qd = ws[kernels.QD : kernels.QD + 3]
        self._q_model = ws[kernels.Q_MODEL : kernels.Q_MODEL + 3]
        self._qd_model = ws[kernels.QD_MODEL : kernels.QD_MODEL + 3]
        self._tau_commanded = ws[kernels.TAU_COMMANDED : kernels.TAU_COMMANDED + 3]
        self._tau_applied = ws[kernels.TAU_APPLIED : kernels.TAU_APPLIED + 3]
        self._mass = ws[kernels.MASS : kernels.MASS + 9].reshape(3, 3)
        self._jac = ws[kernels.JACOBIAN : kernels.JACOBIAN + 9].reshape(3, 3)
        self._p = ws[kernels.TIP : kernels.TIP + 3]
        self._q_measured = ws[kernels.Q_MEASURED : kernels.Q_MEASURED + 3]
        self._force = ws[kernels.FORCE : kernels.FORCE + 3]
        self._reading_values = ws[kernels.READING : kernels.READING + 9]
        self._effects: tuple[PlantEffect, ...] = ()
        self._effect_table: np.ndarray | None = np.zeros((0, 7))
        self.effects = tuple(effects)
        self._contact: PlaneContact | None = None
        self._contact_parameters = np.zeros(0)
        self._friction: TrueFriction | None = None
        self._friction_parameters = np.zeros(0)
        self.friction = self.config.friction
        self._rng = np.random.default_rng(seed)
        self._noise = np.zeros((0, 3))
        self._noise_index = 0
        q0 = 0.5 * (description.q_min_rad + description.q_max_rad) if q0_rad is None else q0_rad
        self._set_state(q0, np.zeros(3) if qd0_rad_s is None else qd0_rad_s, None)
        self.contact = contact
        self._warm_up()

    def _warm_up(self) -> None:
        # Compile (or load from numba's cache) the tick's kernels here, not in the first tick.
        scratch = self._ws.copy()
        kernels.clip_command(np.zeros(3), self._limit, scratch, np.empty(3), np.empty(3, bool))
        if self._effect_table is not None:
            kernels.integrate_tick(
                scratch,
                self._constants,
                self._friction_parameters,
                self._contact_parameters,
                self._effect_table,
                self._noise,
                -1,
            )

    # What acts on the plant (settable: the compiled parameters follow) -----------------------

    @property
    def effects(self) -> tuple[PlantEffect, ...]:
        """The switched-on effects."""
        return self._effects

    @effects.setter
    def effects(self, effects: Sequence[PlantEffect]) -> None:
        self._effects, self._effect_table = checked_effects(effects, 3)

    @property
    def contact(self) -> PlaneContact | None:
        """The tissue, or ``None``."""
        return self._contact

    @contact.setter
    def contact(self, contact: PlaneContact | None) -> None:
        self._contact = contact
        self._contact_parameters = (
            np.zeros(0) if contact is None else np.array(contact.kernel_parameters)
        )
        kernels.contact_force_into(self._ws, self._contact_parameters)

    @property
    def friction(self) -> TrueFriction | None:
        """The true friction (``None``: frictionless)."""
        return self._friction

    @friction.setter
    def friction(self, friction: TrueFriction | None) -> None:
        self._friction = friction
        self._friction_parameters = (
            np.zeros(0) if friction is None else np.array(friction.kernel_parameters)
        )

    # Device interface -------------------------------------------------------------------------

    @property
    def n_joints(self) -> int:
        """Always 3."""
        return 3

    @property
    def control_period_s(self) -> float:
        """The configured control tick [s]."""
        return self.config.control_period_s

    def read(self) -> DeviceReading:
        """Quantized angles, last commanded torque and true tip force at the current tick."""
        self._check_open()
        return _reading(self._ws.item(kernels.TIME), self._reading_values)

    def command_torque(self, tau_nm: ArrayLike) -> TorqueCommand:
        """Clip ``tau_nm`` (3,) to the torque limit and send it; it acts from the next tick.

        The base class's checks and clipping, compiled (same results and errors).

        Raises:
            DataError: on a wrong shape or a non-finite torque (nothing is sent).
            DeviceClosedError: after :meth:`close`.

        """
        self._check_open()
        tau = np.asarray(tau_nm, dtype=float)
        if tau.shape != (3,):
            raise DataError(f"expected {self.n_joints} torques, got shape {tau.shape}")
        out = np.empty(3)
        clipped = np.empty(3, dtype=bool)
        count = kernels.clip_command(tau, self._limit, self._ws, out, clipped)
        if count < 0:
            raise DataError(f"non-finite torque command {tau}")
        if count:
            self._clip_count += 1
        return _torque_command(out, clipped)

    def _send_torque(self, tau_nm: np.ndarray) -> None:
        self._tau_commanded[:] = tau_nm

    def _close(self) -> None:
        self._tau_commanded[:] = 0.0

    def step(self) -> None:
        """Integrate one control tick under the last commanded torque plus actuator noise."""
        self._check_open()
        row = self._next_noise_row()
        if self._effect_table is None:
            self._tau_applied[:] = self._tau_commanded + (
                self._noise[row] if row >= 0 else np.zeros(3)
            )
            self._integrate_tick_python(self._tau_applied.copy())
        elif not kernels.integrate_tick(
            self._ws,
            self._constants,
            self._friction_parameters,
            self._contact_parameters,
            self._effect_table,
            self._noise,
            row,
        ):
            raise ModelError(f"simulation diverged at t = {self.t_s:.4f} s")
        self._refresh()

    # Ground truth -----------------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        """Simulated time [s]."""
        return self._ws.item(kernels.TIME)

    @property
    def q_true_rad(self) -> np.ndarray:
        """True (unquantized) joint angles."""
        return self._q.copy()

    @property
    def qd_true_rad_s(self) -> np.ndarray:
        """True joint velocities."""
        return self._qd.copy()

    @property
    def tau_applied_nm(self) -> np.ndarray:
        """Torque that acted during the last tick: commanded (clipped) plus actuator noise."""
        return self._tau_applied.copy()

    def set_state(self, q_rad: np.ndarray, qd_rad_s: np.ndarray, t_s: float | None = None) -> None:
        """Teleport the plant to ``(q, qd)`` (and time ``t_s`` if given)."""
        self._set_state(q_rad, qd_rad_s, t_s)

    def _set_state(self, q_rad: ArrayLike, qd_rad_s: ArrayLike, t_s: float | None) -> None:
        q = np.asarray(q_rad, dtype=float).reshape(-1)
        qd = np.asarray(qd_rad_s, dtype=float).reshape(-1)
        if (
            q.shape != (3,)
            or qd.shape != (3,)
            or not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd)))
        ):
            raise DataError(f"state needs 3 finite angles and velocities, got {q}, {qd}")
        self._q[:] = q
        self._qd[:] = qd
        if t_s is not None:
            self._ws[kernels.TIME] = float(t_s)
        kernels.to_model_coordinates(self._ws, self._constants)
        self._refresh()

    def measured_q_rad(self) -> np.ndarray:
        """Return the encoder reading: the true angles rounded to the encoder resolution."""
        return self._q_measured.copy()

    def tip_position_in_base_m(self) -> np.ndarray:
        """Return the true tip position [m]."""
        return self._p.copy()

    def tip_velocity_in_base_m_s(self) -> np.ndarray:
        """Return the true tip velocity [m/s]."""
        return self._jac @ self._qd

    def contact_force_in_base_n(self) -> np.ndarray:
        """Return the true force of the tip on the environment [N] (zeros without contact)."""
        return self._force.copy()

    def friction_torque_nm(self) -> np.ndarray:
        """Return the true friction torque at the current velocity (zeros without friction)."""
        if self.friction is None:
            return np.zeros(3)
        return self.friction.torque(self._qd.copy())

    def effects_torque_nm(self, tau_motor_nm: np.ndarray | None = None) -> np.ndarray:
        """Sum of the effects' torques at the current state (``tau_motor`` default: applied)."""
        tau = self._tau_applied if tau_motor_nm is None else np.asarray(tau_motor_nm, dtype=float)
        total = np.zeros(3)
        for effect in self.effects:
            total += effect.torque(self.t_s, self._q, self._qd, tau)
        return total

    def spring_torque_nm(self) -> np.ndarray:
        """Gravity-compensation spring torque at the current angles."""
        tau = np.zeros(3)
        for joint, rest, stiffness in self._springs:
            tau[joint] += stiffness * (self._q[joint] - rest)
        return tau

    def holding_torque_nm(self, q_rad: np.ndarray | None = None) -> np.ndarray:
        """Torque that holds the plant still at ``q`` (gravity plus spring), default: now."""
        q = self._q.copy() if q_rad is None else np.asarray(q_rad, dtype=float)
        tau = self.robot.gravity_torque(q)
        for joint, rest, stiffness in self._springs:
            tau[joint] += stiffness * (q[joint] - rest)
        return tau

    def mechanical_energy_j(self) -> np.ndarray:
        """``[kinetic, gravity potential, spring potential]`` at the current state [J]."""
        kinetic = 0.5 * float(self._qd @ self._mass @ self._qd)
        potential = float(
            pin.computePotentialEnergy(
                self.robot.model, self.robot.data, self.robot.to_model(self._q)
            )
        )
        spring = sum(0.5 * k * (self._q[j] - rest) ** 2 for j, rest, k in self._springs)
        return np.array([kinetic, potential, spring])

    # Internals --------------------------------------------------------------------------------

    def _refresh(self) -> None:
        self._terms.refresh(
            self._ws, self._q_model, self._qd_model, self._constants, self._contact_parameters
        )

    def _next_noise_row(self) -> int:
        """Row of the noise block for this tick (drawn 4096 ticks at a time), -1 for no noise."""
        std = self.config.torque_noise_std_nm
        if std == 0.0:
            return -1
        if self._noise_index >= self._noise.shape[0]:
            self._noise = self._rng.normal(0.0, std, size=(_NOISE_BLOCK_TICKS, 3))
            self._noise_index = 0
        self._noise_index += 1
        return self._noise_index - 1

    def _integrate_tick_python(self, tau_applied: np.ndarray) -> None:
        # The kernel's integration in Python, for effects the kernels do not know (their
        # ``joint_torque`` and ``velocity_slope`` are called at every sub-step).
        h = self.config.control_period_s / self.config.substeps
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = self._mass.ravel().tolist()
        b0, b1, b2 = self._ws[kernels.BIAS : kernels.BIAS + 3].tolist()
        t0, t1, t2 = tau_applied.tolist()
        r0, r1, r2 = t0 - b0, t1 - b1, t2 - b2
        j00, j01, j02, j10, j11, j12, j20, j21, j22 = self._jac.ravel().tolist()
        px0, py0, pz0 = self._p.tolist()
        q_start = self._q.tolist()
        q0, q1, q2 = q_start
        v0, v1, v2 = self._qd.tolist()
        friction = self.friction.evaluate_floats if self.friction is not None else None
        contact = self.contact.environment_force_floats if self.contact is not None else None
        c = self._constants
        spring0, rest0, spring1, rest1, spring2, rest2 = c[
            kernels.SPRINGS : kernels.SPRINGS + 6
        ].tolist()
        t = self.t_s
        for _ in range(self.config.substeps):
            a0, a1, a2 = r0, r1, r2
            d00 = d11 = d12 = d21 = d22 = 0.0
            if friction is not None:
                f0, f1, f2, d00, d11, d12, d21, d22 = friction(v0, v1, v2)
                a0 -= f0
                a1 -= f1
                a2 -= f2
            a0 -= spring0 * (q0 - rest0)
            a1 -= spring1 * (q1 - rest1)
            a2 -= spring2 * (q2 - rest2)
            if contact is not None:
                dq0, dq1, dq2 = q0 - q_start[0], q1 - q_start[1], q2 - q_start[2]
                fx, fy, fz = contact(
                    px0 + j00 * dq0 + j01 * dq1 + j02 * dq2,
                    py0 + j10 * dq0 + j11 * dq1 + j12 * dq2,
                    pz0 + j20 * dq0 + j21 * dq1 + j22 * dq2,
                    j00 * v0 + j01 * v1 + j02 * v2,
                    j10 * v0 + j11 * v1 + j12 * v2,
                    j20 * v0 + j21 * v1 + j22 * v2,
                )
                a0 += j00 * fx + j10 * fy + j20 * fz
                a1 += j01 * fx + j11 * fy + j21 * fz
                a2 += j02 * fx + j12 * fy + j22 * fz
            e, slope = self._effects_now(t, (q0, q1, q2), (v0, v1, v2), tau_applied)
            a0 -= e[0]
            a1 -= e[1]
            a2 -= e[2]
            d00 += slope[0]
            d11 += slope[1]
            d22 += slope[2]
            # Solve (M + h D) qdd = a by Cramer's rule.
            c00, c01, c02 = m00 + h * d00, m01, m02
            c10, c11, c12 = m10, m11 + h * d11, m12 + h * d12
            c20, c21, c22 = m20, m21 + h * d21, m22 + h * d22
            k0 = c11 * c22 - c12 * c21
            k1 = c12 * c20 - c10 * c22
            k2 = c10 * c21 - c11 * c20
            inv_det = 1.0 / (c00 * k0 + c01 * k1 + c02 * k2)
            qdd0 = (a0 * k0 + c01 * (a2 * c12 - a1 * c22) + c02 * (a1 * c21 - a2 * c11)) * inv_det
            qdd1 = (c00 * (a1 * c22 - a2 * c12) + a0 * k1 + c02 * (a2 * c10 - a1 * c20)) * inv_det
            qdd2 = (c00 * (a2 * c11 - a1 * c21) + c01 * (a1 * c20 - a2 * c10) + a0 * k2) * inv_det
            v0 += h * qdd0
            v1 += h * qdd1
            v2 += h * qdd2
            q0 += h * v0
            q1 += h * v1
            q2 += h * v2
            t += h
        if not all(math.isfinite(x) for x in (q0, q1, q2, v0, v1, v2)):
            raise ModelError(f"simulation diverged at t = {self.t_s:.4f} s")
        self._q[:] = (q0, q1, q2)
        self._qd[:] = (v0, v1, v2)
        self._ws[kernels.TIME] += self.config.control_period_s
        kernels.to_model_coordinates(self._ws, self._constants)

    def _effects_now(
        self,
        t_s: float,
        q: tuple[float, float, float],
        qd: tuple[float, float, float],
        tau: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        q_array = np.array(q)
        qd_array = np.array(qd)
        torque = np.zeros(3)
        slope = np.zeros(3)
        for effect in self.effects:
            torque[effect.joint] += effect.joint_torque(t_s, q_array, qd_array, tau)
            slope[effect.joint] += effect.velocity_slope(t_s, q_array, qd_array, tau)
        return torque, slope
