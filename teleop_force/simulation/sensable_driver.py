"""sawSensablePhantom's device loop over the simulated Omni: what one 1 kHz haptic frame does.

The real driver (jhu-saw/sawSensablePhantom, ``core/components/code/mtsSensableHD.cpp``,
``mtsSensableHD::Run``; its lines are quoted in docs/real_robot.md and
``teleop_force/robots/drivers/sensable_phantom.toml``) runs, every 1 ms frame::

    read HD_CURRENT_TRANSFORM, HD_LAST_FORCE, HD_CURRENT_JOINT_ANGLES, HD_LAST_JOINT_TORQUE
    force = servo_cf's force - viscosity * v                  (cf mode)
          | -p_gain * (p - p_hold) - d_gain * v               (cp mode: ``hold``)
          | nothing                                           (no mode yet)
    clamp |force| to m_max_force (2 N); hdSetDoublev(HD_CURRENT_FORCE)
    publish-side state: positions = the driver's transform of the raw angles
    ProcessQueuedCommands()   (servo_cf / hold / free take effect from the next frame)

:class:`SimulatedSensableDevice` does the same on a
:class:`~teleop_force.simulation.plant.SimulatedOmni`: OpenHaptics' raw joint angles are the
plant's measured (encoder-quantized) angles, which are the model's motor coordinates (the
driver table's premise); the Cartesian force becomes joint torques ``tau = J(q)^T F`` with
the model's tip Jacobian at those angles (OpenHaptics' own kinematics in the real device);
``HD_LAST_FORCE`` / ``HD_LAST_JOINT_TORQUE`` are the force and (clipped) torque commanded in
the previous frame. Nothing else acts: the driver adds no gravity compensation
(``use_gravity_compensation`` is an empty function), so a free arm moves under gravity
against the plant's spring and friction.

Simplifications (docs/real_robot.md, "The simulated driver"): the tip velocity ``v`` of the
hold and viscosity terms is the plant's true one (OpenHaptics' HD_CURRENT_VELOCITY filter is
not in the sources); a frame in which no mode is set commands zero force; the device is
homed from the start (the real driver re-zeroes its modes once calibration completes); there
is no gimbal (its angles and torques are 0) and no stylus orientation.
"""

from __future__ import annotations

import enum
import math
import threading
from dataclasses import dataclass

import numpy as np

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.robots.driver_interface import DriverInterface
from teleop_force.robots.registry import builtin_driver
from teleop_force.simulation.plant import SimulatedOmni

#: The driver's JointState names ([cpp] 93-98): the model's three, then the gimbal's.
JOINT_NAMES = ("waist", "shoulder", "elbow", "yaw", "pitch", "roll")
#: Gimbal joints (positions and efforts 0: the simulated Omni has no gimbal).
GIMBAL_JOINTS = 3


@dataclass(frozen=True)
class SensableSettings:
    """The driver's defaults (``mtsSensableHDDevice`` constructor, [cpp] 70-74).

    Attributes:
        max_force_n: ``m_max_force``: the commanded force's norm is clamped to it.
        servo_cp_p_gain_n_per_m: ``m_servo_cp_p_gain`` of the ``hold`` (servo_cp) PD.
        servo_cp_d_gain_n_s_per_m: ``m_servo_cp_d_gain``.
        servo_cf_viscosity_n_s_per_m: ``m_servo_cf_viscosity`` (subtracted in cf mode).

    """

    max_force_n: float = 2.0
    servo_cp_p_gain_n_per_m: float = 100.0
    servo_cp_d_gain_n_s_per_m: float = 3.0
    servo_cf_viscosity_n_s_per_m: float = 0.0

    def __post_init__(self) -> None:
        """Every setting finite and >= 0 (the force limit > 0)."""
        for name in (
            "max_force_n",
            "servo_cp_p_gain_n_per_m",
            "servo_cp_d_gain_n_s_per_m",
            "servo_cf_viscosity_n_s_per_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")
        if self.max_force_n == 0.0:
            raise ConfigurationError("max_force_n must be > 0")


class Mode(enum.Enum):
    """The driver's force mode (``m_cf_mode`` / ``m_cp_mode``; servo_ci is not simulated)."""

    NONE = "none"
    CF = "servo_cf"
    CP = "hold"


@dataclass(frozen=True)
class DeviceFrame:
    """What one frame read at its start, and the driver's JointState of it.

    Attributes:
        t_s: The plant's time at the frame's start [s].
        q_raw_rad: ``HD_CURRENT_JOINT_ANGLES`` (the plant's measured angles, motor coordinates).
        tip_in_base_m: ``HD_CURRENT_TRANSFORM``'s translation, in m, from the model's forward
            kinematics at ``q_raw_rad``.
        last_joint_torque_nm: ``HD_LAST_JOINT_TORQUE`` in N m: the torque commanded in the
            previous frame (zeros before the first).
        last_force_in_base_n: ``HD_LAST_FORCE``: the force commanded in the previous frame.
        position: The published positions (6, :data:`JOINT_NAMES` order).
        effort_mnm: The published efforts (6) in mN m.
        force_in_base_n: The force this frame commands (clamped) [N].
        tau_nm: The joint torque this frame commands (``J^T F``, clipped by the plant) [N m].
        mode: The mode the force came from.

    """

    t_s: float
    q_raw_rad: tuple[float, float, float]
    tip_in_base_m: tuple[float, float, float]
    last_joint_torque_nm: tuple[float, float, float]
    last_force_in_base_n: tuple[float, float, float]
    position: tuple[float, ...]
    effort_mnm: tuple[float, ...]
    force_in_base_n: tuple[float, float, float]
    tau_nm: tuple[float, float, float]
    mode: Mode


def _vec3(values: np.ndarray) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return x, y, z


def _finite3(
    values: np.ndarray | tuple[float, float, float], command: str, what: str
) -> np.ndarray:
    """Return ``values`` as 3 finite floats (a copy); DataError naming ``command`` if not."""
    vector = np.array(values, dtype=float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise DataError(f"{command} needs 3 finite {what} components, got {values}")
    return vector


def clamp_force(force_n: np.ndarray, max_force_n: float) -> np.ndarray:
    """Scale ``force_n`` down to norm ``max_force_n`` if longer ([cpp] 353-356)."""
    norm = float(np.linalg.norm(force_n))
    if norm > max_force_n:
        return force_n * (max_force_n / norm)
    return force_n


def driver_joint_state(
    interface: DriverInterface, q_raw_rad: np.ndarray, tau_nm: np.ndarray
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Return the driver's six positions and efforts [mN m] of raw angles and torques.

    The transform is the driver interface's inverse (``to_driver``), not re-derived here;
    the gimbal's three are 0.
    """
    names, position, effort = interface.to_driver(q_raw_rad, tau_nm)
    if names != JOINT_NAMES[: len(names)] or effort is None:
        raise ConfigurationError(f"driver {interface.name} does not name {JOINT_NAMES[:3]}")
    zeros = (0.0,) * GIMBAL_JOINTS
    return (*position.tolist(), *zeros), (*effort.tolist(), *zeros)


class SimulatedSensableDevice:
    """The driver's device loop over ``plant`` (module docstring); one :meth:`frame` a tick.

    Commands (:meth:`servo_cf`, :meth:`servo_cp`, :meth:`hold`, :meth:`free`) may come from
    any thread; they are queued and take effect at the end of the frame, as
    ``ProcessQueuedCommands`` does.
    """

    def __init__(
        self,
        plant: SimulatedOmni,
        settings: SensableSettings | None = None,
        interface: DriverInterface | None = None,
    ) -> None:
        """Wrap ``plant``; ``interface`` defaults to ``builtin_driver("sensable-phantom")``."""
        self.plant = plant
        self.settings = settings if settings is not None else SensableSettings()
        self.interface = interface if interface is not None else builtin_driver("sensable-phantom")
        self.mode = Mode.NONE
        self.servo_cf_n = np.zeros(3)
        self.hold_position_m = np.zeros(3)
        self._last_force = np.zeros(3)
        self._last_tau = np.zeros(3)
        self._tip = np.zeros(3)
        self._queue: list[tuple[Mode, np.ndarray | None]] = []
        self._lock = threading.Lock()
        #: Commands received, by kind (``servo_cf``, ``servo_cp``, ``hold``, ``free``).
        self.commands = {"servo_cf": 0, "servo_cp": 0, "hold": 0, "free": 0}

    # -- commands (any thread) -----------------------------------------------------------------

    def servo_cf(self, force_in_base_n: np.ndarray | tuple[float, float, float]) -> None:
        """Queue ``servo_cf``: this force from the next frame on, until another command.

        Raises:
            DataError: a force that is not 3 finite numbers (nothing is queued).

        """
        self._command("servo_cf", Mode.CF, _finite3(force_in_base_n, "servo_cf", "force"))

    def servo_cp(self, position_in_base_m: np.ndarray | tuple[float, float, float]) -> None:
        """Queue ``servo_cp``: the driver's Cartesian PD toward this tip position [m].

        Raises:
            DataError: a position that is not 3 finite numbers (nothing is queued).

        """
        self._command("servo_cp", Mode.CP, _finite3(position_in_base_m, "servo_cp", "position"))

    def hold(self) -> None:
        """Queue ``hold``: servo_cp to the position measured in the frame it is processed in."""
        self._command("hold", Mode.CP, None)

    def free(self) -> None:
        """Queue ``free``: servo_cf with a zero force (``use_gravity_compensation`` is a no-op)."""
        self._command("free", Mode.CF, np.zeros(3))

    def _command(self, kind: str, mode: Mode, value: np.ndarray | None) -> None:
        with self._lock:
            self._queue.append((mode, value))
            self.commands[kind] += 1

    # -- the frame -----------------------------------------------------------------------------

    def frame(self) -> DeviceFrame:
        """Run one haptic frame: read, command the force, process the queued commands, step."""
        plant, settings = self.plant, self.settings
        reading = plant.read()
        q = np.array(reading.q_rad)
        tip = plant.robot.tip_position_in_base(q)
        self._tip = tip
        last_force, last_tau = self._last_force, self._last_tau
        velocity = plant.tip_velocity_in_base_m_s()
        if self.mode is Mode.CF:
            force = self.servo_cf_n - settings.servo_cf_viscosity_n_s_per_m * velocity
        elif self.mode is Mode.CP:
            force = (
                -settings.servo_cp_p_gain_n_per_m * (tip - self.hold_position_m)
                - settings.servo_cp_d_gain_n_s_per_m * velocity
            )
        else:
            force = np.zeros(3)
        force = clamp_force(force, settings.max_force_n)
        tau = plant.robot.tip_jacobian_in_base(q).T @ force
        command = plant.command_torque(tau)
        position, effort = driver_joint_state(self.interface, q, last_tau)
        frame = DeviceFrame(
            t_s=reading.t_s,
            q_raw_rad=_vec3(q),
            tip_in_base_m=_vec3(tip),
            last_joint_torque_nm=_vec3(last_tau),
            last_force_in_base_n=_vec3(last_force),
            position=position,
            effort_mnm=effort,
            force_in_base_n=_vec3(force),
            tau_nm=_vec3(command.tau_nm),
            mode=self.mode,
        )
        self._last_force = force
        self._last_tau = np.array(command.tau_nm)
        self._process_queued_commands()
        plant.step()
        return frame

    def _process_queued_commands(self) -> None:
        with self._lock:
            queue, self._queue = self._queue, []
        for mode, value in queue:
            self.mode = mode
            if mode is Mode.CF and value is not None:
                self.servo_cf_n = value
            elif mode is Mode.CP:  # hold: the position now; servo_cp: the one given
                self.hold_position_m = self._tip.copy() if value is None else value
