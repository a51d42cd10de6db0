"""The :class:`Device` interface: what a torque-controlled haptic arm offers a control loop.

A real Omni driver and the simulated Omni (:mod:`teleop_force.simulation.plant`) implement the
same small interface, in the spirit of upkie's backends: read the joint state, command motor
torques, advance one control tick, close. Torque commands are checked and clipped here, in the
base class, so every device clips the same way and reports it::

    with SimulatedOmni(seed=0) as device:
        for _ in range(1000):
            state = device.read()
            device.command_torque(controller(state))
            device.step()
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import TracebackType
from typing import Self

import numpy as np
from numpy.typing import ArrayLike

from teleop_force.errors import ConfigurationError, DataError, TeleopForceError


class DeviceClosedError(TeleopForceError, RuntimeError):
    """A device was used after :meth:`Device.close`."""


def _frozen_vector(value: ArrayLike, name: str, size: int | None = None) -> np.ndarray:
    array = np.array(value, dtype=float)
    if array.ndim != 1 or (size is not None and array.shape[0] != size):
        expected = "a vector" if size is None else f"{size} values"
        raise DataError(f"{name} must be {expected}, got shape {array.shape}")
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class DeviceReading:
    """One reading of a device, in motor coordinates (docs/conventions.md).

    Attributes:
        t_s: Device time of the reading [s].
        q_rad: Measured (encoder) joint angles, shape (n,).
        tau_nm: Last commanded (already clipped) motor torques, shape (n,).
        f_tip_in_base_n: Ground-truth force of the tip on the environment in the base frame,
            shape (3,), or ``None`` when the device has no force sensor.

    """

    t_s: float
    q_rad: np.ndarray
    tau_nm: np.ndarray
    f_tip_in_base_n: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_s", float(self.t_s))
        q = _frozen_vector(self.q_rad, "q_rad")
        object.__setattr__(self, "q_rad", q)
        object.__setattr__(self, "tau_nm", _frozen_vector(self.tau_nm, "tau_nm", q.shape[0]))
        if self.f_tip_in_base_n is not None:
            force = _frozen_vector(self.f_tip_in_base_n, "f_tip_in_base_n", 3)
            object.__setattr__(self, "f_tip_in_base_n", force)

    @property
    def n_joints(self) -> int:
        """Number of joints in the reading."""
        return int(self.q_rad.shape[0])


@dataclass(frozen=True)
class TorqueCommand:
    """What :meth:`Device.command_torque` sent: the clipped torques and which joints clipped."""

    tau_nm: np.ndarray
    clipped: np.ndarray

    @property
    def any_clipped(self) -> bool:
        """Whether at least one joint's torque was clipped."""
        return bool(np.any(self.clipped))


class Device(ABC):
    """A torque-controlled arm sampled at a fixed control period.

    Subclasses implement :attr:`n_joints`, :attr:`control_period_s`, :meth:`read`,
    :meth:`_send_torque`, :meth:`step` and :meth:`_close`; the base class validates and clips
    commands, counts clipped commands and refuses use after :meth:`close`.
    """

    def __init__(self, torque_limit_nm: ArrayLike) -> None:
        """Set the symmetric per-joint torque limit [N m] (a scalar or one value per joint)."""
        limit = np.array(torque_limit_nm, dtype=float).reshape(-1)
        if limit.size == 0 or np.any(~(limit > 0.0)) or np.any(~np.isfinite(limit)):
            raise ConfigurationError(f"torque limit must be finite and > 0, got {limit}")
        self._torque_limit_nm = limit
        self._clip_count = 0
        self._closed = False

    @property
    @abstractmethod
    def n_joints(self) -> int:
        """Number of actuated joints."""

    @property
    @abstractmethod
    def control_period_s(self) -> float:
        """Duration of one control tick, what :meth:`step` advances [s]."""

    @property
    def torque_limit_nm(self) -> np.ndarray:
        """Per-joint torque limit [N m], shape (n,)."""
        return np.broadcast_to(self._torque_limit_nm, (self.n_joints,)).copy()

    @property
    def clip_count(self) -> int:
        """Number of commands so far in which at least one joint was clipped."""
        return self._clip_count

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    @abstractmethod
    def read(self) -> DeviceReading:
        """Return the latest reading (angles, commanded torques, true force if sensed)."""

    def command_torque(self, tau_nm: ArrayLike) -> TorqueCommand:
        """Clip ``tau_nm`` (n,) to the torque limit and send it; it acts from the next tick.

        Raises:
            DataError: on a wrong shape or a non-finite torque (nothing is sent).
            DeviceClosedError: after :meth:`close`.

        """
        self._check_open()
        tau = np.asarray(tau_nm, dtype=float)
        if tau.shape != (self.n_joints,):
            raise DataError(f"expected {self.n_joints} torques, got shape {tau.shape}")
        if not np.isfinite(tau).all():
            raise DataError(f"non-finite torque command {tau}")
        limit = self._torque_limit_nm
        clipped = np.abs(tau) > limit
        if clipped.any():
            self._clip_count += 1
            tau = np.minimum(np.maximum(tau, -limit), limit)
        else:
            tau = tau.copy()
        self._send_torque(tau)
        return TorqueCommand(tau_nm=tau, clipped=clipped)

    @abstractmethod
    def _send_torque(self, tau_nm: np.ndarray) -> None:
        """Send an already validated and clipped torque command."""

    @abstractmethod
    def step(self) -> None:
        """Advance to the next control tick (simulate it, or wait for it)."""

    def close(self) -> None:
        """Release the device (idempotent); motors are left unpowered."""
        if not self._closed:
            self._close()
            self._closed = True

    @abstractmethod
    def _close(self) -> None:
        """Release the device's resources (called once)."""

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceClosedError(f"{type(self).__name__} is closed")

    def __enter__(self) -> Self:
        """Return the device itself."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Close the device."""
        self.close()
