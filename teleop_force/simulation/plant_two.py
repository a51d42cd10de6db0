"""Plant family two: another simulated Omni behind the ``Device`` interface.

Built apart from family one (:mod:`~teleop_force.simulation.plant`) so that a model identified
on it is a fair held-out test of the library. What differs:

- **arm**: the Omni's kinematics with every link mass, centre of mass and inertia, the rotor
  inertias and the spring stiffness drawn per ``instance_seed`` within +-20 % of the Omni
  description (:mod:`~teleop_force.simulation.perturbed_omni`);
- **dynamics**: its own compiled Newton-Euler code (:mod:`~teleop_force.simulation.chain_dynamics`),
  evaluated at *every* sub-step (family one: pinocchio once per tick, then a linearised tip);
- **friction**: LuGre per joint and a LuGre cable between joints 2 and 3, with bristle states
  (:mod:`~teleop_force.simulation.lugre_friction`), levels perturbed per ``instance_seed``;
- **actuator**: the command goes through a DAC (``dac_step_nm`` quantization), gains a torque
  ripple ``ripple_fraction |tau_i| sin(k q_i)`` (commutation) and *coloured* noise (AR(1),
  ``torque_noise_std_nm`` stationary deviation, ``torque_noise_correlation_s``): family one
  adds white noise to the exact command;
- **encoders**: per-joint resolutions, counting down (``floor``): family one rounds with one
  resolution;
- **contact**: :class:`~teleop_force.simulation.floor_contact.HuntCrossleyFloor` (nonlinear,
  Coulomb sliding); a family-one :class:`~teleop_force.simulation.contact.PlaneContact` is
  accepted too.

Dynamics in motor coordinates, every term on the left as in family one::

    M(q) qdd + C(q, qd) qd + N(q) + k (q2 - pi/2) + tau_LuGre + tau_effects - J^T F_env = tau_a

Integration: each tick (1 ms) is ``substeps`` (default 10) semi-implicit Euler steps. At each
sub-step the rigid-body terms, tip and Jacobian are recomputed, the bristles advance exactly
for the held velocity, and ``(M + h D) qdd = rhs`` is solved with ``D`` the velocity slope of
the damping terms (bristle micro-damping, viscous, the effects' smoothed signs, and the
floor's sliding friction ``c J^T (I - n n^T) J``), so the stiff terms stay stable.

Effects (:mod:`~teleop_force.simulation.effects`) of the built-in classes run compiled at
every sub-step, as in family one; others are evaluated once per tick in Python, from the
commanded torque (zero-order hold). The true friction a session records is the LuGre
torque of the tick's last sub-step: the friction at the sample's state.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError, ModelError
from teleop_force.robots import omni
from teleop_force.robots.description import RobotDescription
from teleop_force.robots.device import Device, DeviceReading, TorqueCommand
from teleop_force.simulation.chain_dynamics import chain_table, motor_terms
from teleop_force.simulation.contact import PlaneContact, plane_contact_force
from teleop_force.simulation.effects import (
    PlantEffect,
    checked_effects,
    effects_torque_slope,
)
from teleop_force.simulation.floor_contact import HuntCrossleyFloor, floor_contact_force
from teleop_force.simulation.lugre_friction import N_STATES, LuGreFriction, lugre_step
from teleop_force.simulation.payload import check_tip_mass, with_tip_payload
from teleop_force.simulation.perturbed_omni import DEFAULT_SPREAD, perturbed_omni_description

#: Either family's contact.
Contact = PlaneContact | HuntCrossleyFloor

_NOISE_BLOCK_TICKS = 4096

# Workspace offsets.
_Q = 0
_QD = 3
_Z = 6  # 4 bristle states
_TAU_COMMANDED = 10
_TAU_APPLIED = 13
_TIME = 16
_FORCE = 17
_FRICTION = 20
_Q_MEASURED = 23
_NOISE = 26
_WORKSPACE_SIZE = 29

# Constant offsets.
_H = 0
_SUBSTEPS = 1
_PERIOD = 2
_RESOLUTION = 3  # 3 floats
_SPRING_K = 6  # 3 floats
_SPRING_REST = 9  # 3 floats
_DAC = 12
_RIPPLE = 13
_RIPPLE_K = 14
_NOISE_A = 15
_NOISE_B = 16
_CONSTANTS_SIZE = 17

_NO_CONTACT, _PLANE, _FLOOR = 0, 1, 2


@dataclass(frozen=True)
class DrawnArm:
    """An arm given instead of drawn from ``instance_seed`` (the plant generator's draws).

    Attributes:
        inertia_seed: Seeds the inertia perturbation (``perturbed_omni_description``).
        spread: Its relative spread.
        friction: The true friction (any LuGre parameters: every drawn law is one).
        spring_scale: The spring stiffness relative to the Omni's.

    """

    inertia_seed: int
    spread: float
    friction: LuGreFriction
    spring_scale: float

    def __post_init__(self) -> None:
        seed = self.inertia_seed
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ConfigurationError(f"inertia_seed must be an integer >= 0, got {seed!r}")
        if not 0.0 <= self.spread < 1.0:
            raise ConfigurationError(f"spread must be in [0, 1), got {self.spread}")
        if not (math.isfinite(self.spring_scale) and self.spring_scale > 0.0):
            raise ConfigurationError(f"spring_scale must be > 0, got {self.spring_scale}")


def _triple(name: str, value: ArrayLike) -> tuple[float, float, float]:
    values = np.broadcast_to(np.asarray(value, dtype=float), (3,))
    if not (np.all(np.isfinite(values)) and np.all(values >= 0.0)):
        raise ConfigurationError(f"{name} must be finite and >= 0, got {value!r}")
    return (float(values[0]), float(values[1]), float(values[2]))


@dataclass(frozen=True)
class PlantTwoConfig:
    """Physical and numerical settings of :class:`SimulatedOmniTwo`.

    Attributes:
        instance_seed: Which arm of the family: seeds the inertias, friction and spring.
        spread: Relative spread of the per-instance perturbation (+-20 %).
        control_period_s: One control tick.
        substeps: Semi-implicit Euler sub-steps per tick.
        torque_limit_nm: Symmetric motor torque limit.
        torque_noise_std_nm: Stationary deviation of the coloured actuator noise.
        torque_noise_correlation_s: Its correlation time (AR(1) pole ``exp(-dt / tc)``).
        dac_step_nm: Quantization step of the applied torque (0: none).
        ripple_fraction: Torque ripple amplitude relative to ``|tau|``.
        ripple_wavenumber_per_rad: Ripple periods per radian of joint angle.
        encoder_resolution_rad: Per-joint encoder count [rad] (0: exact); angles are floored.
        tip_mass_kg: Payload at the tip (:mod:`~teleop_force.simulation.payload`).
        gravity: Whether gravity acts.
        friction: Whether the LuGre friction acts.
        drawn_arm: An arm given whole (inertias, friction, spring) instead of the one of
            ``instance_seed`` (``None``: the family's own).

    """

    instance_seed: int = 0
    spread: float = DEFAULT_SPREAD
    control_period_s: float = 1e-3
    substeps: int = 10
    torque_limit_nm: float = omni.MOTOR_TORQUE_LIMIT_NM
    torque_noise_std_nm: float = 1.5e-3
    torque_noise_correlation_s: float = 4e-3
    dac_step_nm: float = 0.6 / 2048
    ripple_fraction: float = 0.004
    ripple_wavenumber_per_rad: float = 96.0
    encoder_resolution_rad: tuple[float, float, float] = (5.2e-4, 4.6e-4, 4.6e-4)
    tip_mass_kg: float = 0.0
    gravity: bool = True
    friction: bool = True
    drawn_arm: DrawnArm | None = None

    def __post_init__(self) -> None:
        seed = self.instance_seed
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ConfigurationError(f"instance_seed must be an integer >= 0, got {seed!r}")
        if not 0.0 <= self.spread < 1.0:
            raise ConfigurationError(f"spread must be in [0, 1), got {self.spread}")
        if not (math.isfinite(self.control_period_s) and self.control_period_s > 0.0):
            raise ConfigurationError(f"control_period_s must be > 0, got {self.control_period_s}")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int):
            raise ConfigurationError(f"substeps must be an integer >= 1, got {self.substeps}")
        if self.substeps < 1:
            raise ConfigurationError(f"substeps must be an integer >= 1, got {self.substeps}")
        if not (math.isfinite(self.torque_limit_nm) and self.torque_limit_nm > 0.0):
            raise ConfigurationError(f"torque_limit_nm must be > 0, got {self.torque_limit_nm}")
        for name in (
            "torque_noise_std_nm",
            "dac_step_nm",
            "ripple_fraction",
            "ripple_wavenumber_per_rad",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")
        correlation = self.torque_noise_correlation_s
        if not (math.isfinite(correlation) and correlation > 0.0):
            raise ConfigurationError(f"torque_noise_correlation_s must be > 0, got {correlation}")
        resolution = _triple("encoder_resolution_rad", self.encoder_resolution_rad)
        object.__setattr__(self, "encoder_resolution_rad", resolution)
        object.__setattr__(self, "tip_mass_kg", check_tip_mass(self.tip_mass_kg))

    def ideal(self) -> PlantTwoConfig:
        """Return a copy without friction, noise, DAC, ripple and quantization (same arm)."""
        return dataclasses.replace(
            self,
            friction=False,
            torque_noise_std_nm=0.0,
            dac_step_nm=0.0,
            ripple_fraction=0.0,
            encoder_resolution_rad=(0.0, 0.0, 0.0),
        )

    def arm(self) -> tuple[RobotDescription, LuGreFriction | None, float]:
        """Return the instance: ``(description with payload, true friction or None, spring k)``.

        Deterministic in :attr:`instance_seed` and :attr:`spread` (independent of the other
        settings: switching friction off keeps the same masses). A :attr:`drawn_arm` is used
        as given.
        """
        drawn = self.drawn_arm
        if drawn is not None:
            rng = np.random.default_rng(np.random.SeedSequence([3, int(drawn.inertia_seed)]))
            description = with_tip_payload(
                perturbed_omni_description(rng, drawn.spread), self.tip_mass_kg
            )
            stiffness = omni.SPRING_STIFFNESS_NM_PER_RAD * drawn.spring_scale
            return description, (drawn.friction if self.friction else None), stiffness
        rng = np.random.default_rng(np.random.SeedSequence([2, int(self.instance_seed)]))
        description = perturbed_omni_description(rng, self.spread)
        friction = LuGreFriction().perturbed(rng, self.spread)
        stiffness = omni.SPRING_STIFFNESS_NM_PER_RAD * float(
            rng.uniform(1.0 - self.spread, 1.0 + self.spread)
        )
        description = with_tip_payload(description, self.tip_mass_kg)
        return description, (friction if self.friction else None), stiffness


def _contact_parameters(contact: Contact | None) -> tuple[int, np.ndarray]:
    if contact is None:
        return _NO_CONTACT, np.zeros(0)
    if isinstance(contact, HuntCrossleyFloor):
        return _FLOOR, np.array(contact.kernel_parameters)
    if isinstance(contact, PlaneContact):
        return _PLANE, np.array(contact.kernel_parameters)
    raise ConfigurationError(f"not a contact: {contact!r}")


@njit_cached()
def _contact_force(
    code: int, parameters: np.ndarray, p: np.ndarray, v: np.ndarray
) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """Force on the tip and sliding slope for the contact ``code`` (0: none)."""
    if code == _FLOOR:
        return floor_contact_force(parameters, p[0], p[1], p[2], v[0], v[1], v[2])
    if code == _PLANE:
        fx, fy, fz = plane_contact_force(parameters, p[0], p[1], p[2], v[0], v[1], v[2])
        return fx, fy, fz, 0.0
    return 0.0, 0.0, 0.0, 0.0


@njit_cached()
def _matvec(a: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    for i in range(3):
        out[i] = a[i, 0] * x[0] + a[i, 1] * x[1] + a[i, 2] * x[2]


@njit_cached()
def _solve3(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> bool:  # pragma: no cover
    """Solve ``a x = b`` (3 x 3) by Cramer's rule into ``out``; False if singular."""
    k0 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    k1 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    k2 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * k0 + a[0, 1] * k1 + a[0, 2] * k2
    if det == 0.0 or not math.isfinite(det):
        return False
    inv = 1.0 / det
    out[0] = (b[0] * k0 + a[0, 1] * (b[2] * a[1, 2] - b[1] * a[2, 2])
              + a[0, 2] * (b[1] * a[2, 1] - b[2] * a[1, 1])) * inv  # fmt: skip
    out[1] = (a[0, 0] * (b[1] * a[2, 2] - b[2] * a[1, 2]) + b[0] * k1
              + a[0, 2] * (b[2] * a[1, 0] - b[1] * a[2, 0])) * inv  # fmt: skip
    out[2] = (a[0, 0] * (b[2] * a[1, 1] - b[1] * a[2, 1])
              + a[0, 1] * (b[1] * a[2, 0] - b[2] * a[1, 0]) + b[0] * k2) * inv  # fmt: skip
    return True


@njit_cached()
def _finish(
    ws: np.ndarray, table: np.ndarray, constants: np.ndarray, code: int, contact: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Write the encoder reading and contact force at the workspace's state."""
    for i in range(3):
        resolution = constants[_RESOLUTION + i]
        q = ws[_Q + i]
        ws[_Q_MEASURED + i] = q if resolution == 0.0 else math.floor(q / resolution) * resolution
    mass = np.empty((3, 3))
    bias = np.empty(3)
    jac = np.empty((3, 3))
    tip = np.empty(3)
    qd = ws[_QD : _QD + 3].copy()
    motor_terms(table, ws[_Q : _Q + 3].copy(), qd, mass, bias, jac, tip)
    v_tip = np.empty(3)
    _matvec(jac, qd, v_tip)
    fx, fy, fz, _ = _contact_force(code, contact, tip, v_tip)
    ws[_FORCE], ws[_FORCE + 1], ws[_FORCE + 2] = -fx, -fy, -fz


@njit_cached()
def integrate_tick_two(
    ws: np.ndarray,
    table: np.ndarray,
    constants: np.ndarray,
    friction: np.ndarray,
    code: int,
    contact: np.ndarray,
    effects: np.ndarray,
    extra_nm: np.ndarray,
    innovation: np.ndarray,
) -> bool:  # pragma: no cover - compiled
    """Advance the workspace by one tick; ``False`` (state kept) if it diverged.

    ``innovation`` (3,) is the tick's standard normal draw for the coloured noise (empty: no
    noise); ``extra_nm`` the effects evaluated in Python for this tick (zeros: none).
    """
    # The actuator: DAC, ripple at the tick's start angles, coloured noise (AR(1)).
    dac = constants[_DAC]
    for i in range(3):
        command = ws[_TAU_COMMANDED + i]
        applied = command if dac == 0.0 else np.rint(command / dac) * dac
        applied += constants[_RIPPLE] * abs(command) * math.sin(constants[_RIPPLE_K] * ws[_Q + i])
        if innovation.size > 0:
            ws[_NOISE + i] = (
                constants[_NOISE_A] * ws[_NOISE + i] + constants[_NOISE_B] * innovation[i]
            )
            applied += ws[_NOISE + i]
        ws[_TAU_APPLIED + i] = applied
    h = constants[_H]
    q = ws[_Q : _Q + 3].copy()
    qd = ws[_QD : _QD + 3].copy()
    z = ws[_Z : _Z + N_STATES].copy()
    tau = ws[_TAU_APPLIED : _TAU_APPLIED + 3].copy()
    t = ws[_TIME]
    mass = np.empty((3, 3))
    bias = np.empty(3)
    jac = np.empty((3, 3))
    tip = np.empty(3)
    slope = np.empty((3, 3))
    rhs = np.empty(3)
    qdd = np.empty(3)
    friction_now = np.zeros(3)
    v_tip = np.empty(3)
    sliding = np.empty((3, 3))
    system = np.empty((3, 3))
    normal = np.zeros(3)
    if code != _NO_CONTACT:
        normal[0], normal[1], normal[2] = contact[0], contact[1], contact[2]
    has_friction = friction.size > 0
    has_effects = effects.shape[0] > 0
    for _ in range(int(constants[_SUBSTEPS])):
        motor_terms(table, q, qd, mass, bias, jac, tip)
        slope[:, :] = 0.0
        for i in range(3):
            rhs[i] = tau[i] - bias[i] - extra_nm[i]
            rhs[i] -= constants[_SPRING_K + i] * (q[i] - constants[_SPRING_REST + i])
        if has_friction:
            f0, f1, f2, d11, d22, d23, d32, d33 = lugre_step(friction, z, qd[0], qd[1], qd[2], h)
            friction_now[0], friction_now[1], friction_now[2] = f0, f1, f2
            rhs[0] -= f0
            rhs[1] -= f1
            rhs[2] -= f2
            slope[0, 0] += d11
            slope[1, 1] += d22
            slope[1, 2] += d23
            slope[2, 1] += d32
            slope[2, 2] += d33
        if code != _NO_CONTACT:
            _matvec(jac, qd, v_tip)
            fx, fy, fz, c = _contact_force(code, contact, tip, v_tip)
            for i in range(3):
                rhs[i] += jac[0, i] * fx + jac[1, i] * fy + jac[2, i] * fz
            if c > 0.0:
                # sliding friction, implicitly: c J^T (I - n n^T) J = c Jt^T Jt
                for j in range(3):
                    along = normal[0] * jac[0, j] + normal[1] * jac[1, j] + normal[2] * jac[2, j]
                    for a in range(3):
                        sliding[a, j] = jac[a, j] - normal[a] * along
                for i in range(3):
                    for j in range(3):
                        slope[i, j] += c * (
                            sliding[0, i] * sliding[0, j]
                            + sliding[1, i] * sliding[1, j]
                            + sliding[2, i] * sliding[2, j]
                        )
        if has_effects:
            e0, e1, e2, g0, g1, g2 = effects_torque_slope(
                effects, t, q[0], q[1], q[2], qd[0], qd[1], qd[2], tau[0], tau[1], tau[2]
            )
            rhs[0] -= e0
            rhs[1] -= e1
            rhs[2] -= e2
            slope[0, 0] += g0
            slope[1, 1] += g1
            slope[2, 2] += g2
        for i in range(3):
            for j in range(3):
                system[i, j] = mass[i, j] + h * slope[i, j]
        if not _solve3(system, rhs, qdd):
            return False
        for i in range(3):
            qd[i] += h * qdd[i]
            q[i] += h * qd[i]
        t += h
    for i in range(3):
        if not (math.isfinite(q[i]) and math.isfinite(qd[i])):
            return False
    ws[_Q : _Q + 3] = q
    ws[_QD : _QD + 3] = qd
    ws[_Z : _Z + N_STATES] = z
    ws[_FRICTION : _FRICTION + 3] = friction_now
    ws[_TIME] += constants[_PERIOD]
    _finish(ws, table, constants, code, contact)
    return True


@njit_cached()
def _clip(
    tau: np.ndarray, limit: float, ws: np.ndarray, out: np.ndarray, clipped: np.ndarray
) -> int:  # pragma: no cover - compiled
    """Clip to ``+-limit`` into ``out`` and the workspace; -1 if not finite, else # clipped."""
    for i in range(3):
        if not math.isfinite(tau[i]):
            return -1
    count = 0
    for i in range(3):
        x = tau[i]
        over = abs(x) > limit
        clipped[i] = over
        if over:
            count += 1
            x = min(max(x, -limit), limit)
        out[i] = x
        ws[_TAU_COMMANDED + i] = x
    return count


class SimulatedOmniTwo(Device):
    """Plant family two (module docstring): a perturbed Omni with LuGre friction.

    ``read()`` returns the floored encoder angles, the last commanded torque and the true
    contact force (zeros without contact). Truth for tests: :attr:`q_true_rad`,
    :attr:`qd_true_rad_s`, :attr:`tau_applied_nm`, :meth:`friction_torque_nm`...
    """

    def __init__(
        self,
        config: PlantTwoConfig | None = None,
        *,
        seed: int | np.random.SeedSequence | None = 0,
        effects: Sequence[PlantEffect] = (),
        contact: Contact | None = None,
        q0_rad: ArrayLike | None = None,
        qd0_rad_s: ArrayLike | None = None,
    ) -> None:
        """Create the arm of ``config.instance_seed`` at ``q0_rad`` (default mid-range), at rest.

        ``seed`` seeds the actuator noise only (the arm comes from the config).
        """
        self.config = config if config is not None else PlantTwoConfig()
        super().__init__(self.config.torque_limit_nm)
        description, friction, spring_k = self.config.arm()
        self.description = description
        self.true_friction = friction
        self.spring_stiffness_nm_per_rad = spring_k
        self._table = chain_table(description, gravity=self.config.gravity)
        self._constants = self._pack_constants(description, spring_k)
        self._friction_parameters = (
            np.zeros(0) if friction is None else np.array(friction.kernel_parameters)
        )
        self._ws = np.zeros(_WORKSPACE_SIZE)
        self._rng = np.random.default_rng(seed)
        self._noise = np.zeros((0, 3))
        self._noise_index = 0
        self._no_noise = np.zeros(0)
        self._extra = np.zeros(3)
        self._effects: tuple[PlantEffect, ...] = ()
        self._effect_table: np.ndarray | None = np.zeros((0, 7))
        self.effects = tuple(effects)
        self._contact: Contact | None = None
        self._contact_code = _NO_CONTACT
        self._contact_parameters = np.zeros(0)
        q0 = (
            0.5 * (description.q_min_rad + description.q_max_rad)
            if q0_rad is None
            else np.asarray(q0_rad, dtype=float)
        )
        self.set_state(q0, np.zeros(3) if qd0_rad_s is None else np.asarray(qd0_rad_s))
        self.contact = contact
        if self.config.torque_noise_std_nm > 0.0:
            # start the coloured noise in its stationary distribution
            self._ws[_NOISE : _NOISE + 3] = self._rng.normal(
                0.0, self.config.torque_noise_std_nm, 3
            )

    def _pack_constants(self, description: RobotDescription, spring_k: float) -> np.ndarray:
        config = self.config
        constants = np.zeros(_CONSTANTS_SIZE)
        constants[_H] = config.control_period_s / config.substeps
        constants[_SUBSTEPS] = config.substeps
        constants[_PERIOD] = config.control_period_s
        constants[_RESOLUTION : _RESOLUTION + 3] = config.encoder_resolution_rad
        for spring in description.springs:
            constants[_SPRING_K + spring.joint] = spring_k
            constants[_SPRING_REST + spring.joint] = spring.rest_angle_rad
        constants[_DAC] = config.dac_step_nm
        constants[_RIPPLE] = config.ripple_fraction
        constants[_RIPPLE_K] = config.ripple_wavenumber_per_rad
        a = math.exp(-config.control_period_s / config.torque_noise_correlation_s)
        constants[_NOISE_A] = a
        constants[_NOISE_B] = config.torque_noise_std_nm * math.sqrt(1.0 - a * a)
        return constants

    # What acts on the plant ------------------------------------------------------------------

    @property
    def effects(self) -> tuple[PlantEffect, ...]:
        """The switched-on effects."""
        return self._effects

    @effects.setter
    def effects(self, effects: Sequence[PlantEffect]) -> None:
        self._effects, self._effect_table = checked_effects(effects, 3)

    @property
    def contact(self) -> Contact | None:
        """The floor (or a family-one tissue), or ``None``."""
        return self._contact

    @contact.setter
    def contact(self, contact: Contact | None) -> None:
        code, parameters = _contact_parameters(contact)
        self._contact = contact
        self._contact_code = code
        self._contact_parameters = parameters
        _finish(self._ws, self._table, self._constants, code, parameters)

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
        """Floored encoder angles, last commanded torque and true tip force at this tick."""
        self._check_open()
        ws = self._ws
        values = np.concatenate(
            (ws[_Q_MEASURED : _Q_MEASURED + 3], ws[_TAU_COMMANDED : _TAU_COMMANDED + 3],
             ws[_FORCE : _FORCE + 3])
        )  # fmt: skip
        frozen = np.frombuffer(values.tobytes())  # read-only
        reading = DeviceReading.__new__(DeviceReading)
        vars(reading).update(
            t_s=ws.item(_TIME), q_rad=frozen[0:3], tau_nm=frozen[3:6], f_tip_in_base_n=frozen[6:9]
        )
        return reading

    def command_torque(self, tau_nm: ArrayLike) -> TorqueCommand:
        """Clip ``tau_nm`` (3,) to the torque limit and send it; it acts from the next tick.

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
        count = _clip(tau, float(self._torque_limit_nm[0]), self._ws, out, clipped)
        if count < 0:
            raise DataError(f"non-finite torque command {tau}")
        if count:
            self._clip_count += 1
        command = TorqueCommand.__new__(TorqueCommand)
        vars(command).update(tau_nm=out, clipped=clipped)
        return command

    def _send_torque(self, tau_nm: np.ndarray) -> None:
        self._ws[_TAU_COMMANDED : _TAU_COMMANDED + 3] = tau_nm

    def _close(self) -> None:
        self._ws[_TAU_COMMANDED : _TAU_COMMANDED + 3] = 0.0

    def step(self) -> None:
        """Integrate one control tick under the last commanded torque (through the actuator)."""
        self._check_open()
        table = self._effect_table
        if table is None:
            ws = self._ws
            self._extra = sum(
                (
                    e.torque(ws[_TIME], ws[_Q : _Q + 3], ws[_QD : _QD + 3],
                             ws[_TAU_COMMANDED : _TAU_COMMANDED + 3])
                    for e in self._effects
                ),
                np.zeros(3),
            )  # fmt: skip
            table = np.zeros((0, 7))
        if not integrate_tick_two(
            self._ws,
            self._table,
            self._constants,
            self._friction_parameters,
            self._contact_code,
            self._contact_parameters,
            table,
            self._extra,
            self._next_innovation(),
        ):
            raise ModelError(f"simulation diverged at t = {self.t_s:.4f} s")

    def _next_innovation(self) -> np.ndarray:
        if self.config.torque_noise_std_nm == 0.0:
            return self._no_noise
        if self._noise_index >= self._noise.shape[0]:
            self._noise = self._rng.standard_normal(size=(_NOISE_BLOCK_TICKS, 3))
            self._noise_index = 0
        self._noise_index += 1
        return self._noise[self._noise_index - 1]

    # Ground truth -----------------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        """Simulated time [s]."""
        return self._ws.item(_TIME)

    @property
    def q_true_rad(self) -> np.ndarray:
        """True joint angles."""
        return self._ws[_Q : _Q + 3].copy()

    @property
    def qd_true_rad_s(self) -> np.ndarray:
        """True joint velocities."""
        return self._ws[_QD : _QD + 3].copy()

    @property
    def bristle_state(self) -> np.ndarray:
        """The LuGre bristle deflections ``z`` (joints 1-3, cable) [rad]."""
        return self._ws[_Z : _Z + N_STATES].copy()

    @property
    def tau_applied_nm(self) -> np.ndarray:
        """Torque that acted during the last tick (DAC, ripple and noise included)."""
        return self._ws[_TAU_APPLIED : _TAU_APPLIED + 3].copy()

    def friction_torque_nm(self) -> np.ndarray:
        """Return the true LuGre torque of the last sub-step (zeros before the first step)."""
        return self._ws[_FRICTION : _FRICTION + 3].copy()

    def contact_force_in_base_n(self) -> np.ndarray:
        """Return the true force of the tip on the environment [N] (zeros without contact)."""
        return self._ws[_FORCE : _FORCE + 3].copy()

    def measured_q_rad(self) -> np.ndarray:
        """Return the encoder reading."""
        return self._ws[_Q_MEASURED : _Q_MEASURED + 3].copy()

    def set_state(self, q_rad: ArrayLike, qd_rad_s: ArrayLike, t_s: float | None = None) -> None:
        """Teleport the plant to ``(q, qd)`` (and time ``t_s``); the bristles are relaxed."""
        q = np.asarray(q_rad, dtype=float).reshape(-1)
        qd = np.asarray(qd_rad_s, dtype=float).reshape(-1)
        if q.shape != (3,) or qd.shape != (3,) or not np.all(np.isfinite(np.r_[q, qd])):
            raise DataError(f"state needs 3 finite angles and velocities, got {q}, {qd}")
        self._ws[_Q : _Q + 3] = q
        self._ws[_QD : _QD + 3] = qd
        self._ws[_Z : _Z + N_STATES] = 0.0
        if t_s is not None:
            self._ws[_TIME] = float(t_s)
        _finish(
            self._ws, self._table, self._constants, self._contact_code, self._contact_parameters
        )

    def terms(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(M, C qd + N, J, p)`` at the current state, motor coordinates."""
        mass, bias, jac, tip = np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty(3)
        motor_terms(self._table, self.q_true_rad, self.qd_true_rad_s, mass, bias, jac, tip)
        return mass, bias, jac, tip

    def tip_position_in_base_m(self) -> np.ndarray:
        """Return the true tip position [m]."""
        return self.terms()[3]

    def holding_torque_nm(self, q_rad: ArrayLike | None = None) -> np.ndarray:
        """Torque that holds the arm still at ``q`` (gravity plus spring), default: now."""
        q = self.q_true_rad if q_rad is None else np.asarray(q_rad, dtype=float)
        mass, bias, jac, tip = np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty(3)
        motor_terms(self._table, q, np.zeros(3), mass, bias, jac, tip)
        c = self._constants
        return bias + c[_SPRING_K : _SPRING_K + 3] * (q - c[_SPRING_REST : _SPRING_REST + 3])

    def kinetic_energy_j(self) -> float:
        """``qd' M qd / 2`` [J]."""
        qd = self.qd_true_rad_s
        return 0.5 * float(qd @ self.terms()[0] @ qd)

    def potential_energy_j(self) -> float:
        """Gravity (pinocchio, on the arm's description) plus spring potential energy [J]."""
        model = self.description.model
        if model is None:  # pragma: no cover - chain_table refused it already
            return 0.0
        q = self.q_true_rad
        gravity = 0.0
        if self.config.gravity:
            q_model = np.asarray(self.description.coupling) @ q
            gravity = float(pin.computePotentialEnergy(model, model.createData(), q_model))
        c = self._constants
        stretch = q - c[_SPRING_REST : _SPRING_REST + 3]
        return gravity + float(0.5 * np.sum(c[_SPRING_K : _SPRING_K + 3] * stretch**2))

    def bristle_energy_j(self) -> float:
        """Energy stored in the LuGre bristles [J] (0 without friction)."""
        if self.true_friction is None:
            return 0.0
        return self.true_friction.bristle_energy_j(self.bristle_state)
