"""Checks of a :class:`DriverInterface` against what the driver itself reports.

The driver's own Cartesian pose (``measured_cp``, computed by the vendor library from the raw
encoders) and its commanded force (``measured_cf``) are independent of the description: the
model's forward kinematics of the description's ``q`` must match the first up to a constant
base offset (the vendor's origin is not the model's), and the description's ``tau`` must be
``J(q)^T F`` of the second. A mismatch is explained, where one field can explain it, by
naming the entry and the field (``positions[1].sign``, ``positions[2].offset_rad``,
``effort_unit``). The sanity command calls these on a few seconds of recorded driver data.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from teleop_force.errors import DataError
from teleop_force.robots.driver_interface import EFFORT_UNITS, DriverInterface

#: Forward kinematics: model q (n,) -> tip position in the model's base frame [m] (3,).
TipPosition = Callable[[np.ndarray], np.ndarray]
#: Tip Jacobian: model q (n,) -> d p / d q (3 x n).
TipJacobian = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class CheckResult:
    """One check: whether it passed, the residual, and what explains a failure.

    ``findings`` are one-line messages, each naming a field of the description.
    """

    ok: bool
    residual: float
    findings: tuple[str, ...]
    base_offset_m: np.ndarray | None = None


def _samples(names: Sequence[str], values: np.ndarray, what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != len(names):
        raise DataError(f"{what}: expected (samples, {len(names)}) values, got {arr.shape}")
    return arr


def _fit_residual(
    tip: TipPosition, rotation: np.ndarray, q: np.ndarray, cp: np.ndarray
) -> tuple[float, np.ndarray]:
    """RMS distance [m] between ``cp`` and ``rotation^T fk(q)`` after the best translation."""
    p = np.array([tip(qi) for qi in q]) @ rotation  # rows: R^T p (driver axes)
    r = cp - p
    t = r.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum((r - t) ** 2, axis=1)))), t


def check_positions(
    interface: DriverInterface,
    tip_position: TipPosition,
    names: Sequence[str],
    positions: np.ndarray,
    measured_cp_m: np.ndarray,
    tolerance_m: float = 2.0e-3,
) -> CheckResult:
    """Compare the model's tip of ``to_model(positions)`` with the driver's ``measured_cp``.

    ``positions`` (samples x names) and ``measured_cp_m`` (samples x 3, translation of the
    driver's pose in its base frame, m) come from the same messages; the samples should
    cover the workspace (a sign is invisible where its joint stays at 0). A constant offset
    between the two base frames is fitted and returned. On a failure, each entry's flipped
    sign and each model joint's fitted offset are tried alone; the one that brings the
    residual under ``tolerance_m`` is reported by field.
    """
    x = _samples(names, positions, "positions")
    cp = np.asarray(measured_cp_m, dtype=float)
    if cp.shape != (x.shape[0], 3):
        raise DataError(f"measured_cp: expected ({x.shape[0]}, 3) values, got {cp.shape}")
    rotation = interface.rotation

    def residual_of(candidate: DriverInterface, delta: np.ndarray | None = None) -> float:
        q, _ = candidate.to_model(names, x)
        if delta is not None:
            q = q + delta
        return _fit_residual(tip_position, rotation, q, cp)[0]

    q0, _ = interface.to_model(names, x)
    rms, offset = _fit_residual(tip_position, rotation, q0, cp)
    if rms <= tolerance_m:
        return CheckResult(True, rms, (), offset)
    candidates: list[tuple[float, str]] = []
    for i, entry in enumerate(interface.positions):
        flipped = list(interface.positions)
        flipped[i] = dataclasses.replace(entry, sign=-entry.sign)
        fixed = dataclasses.replace(interface, positions=tuple(flipped))
        value = residual_of(fixed)
        candidates.append(
            (
                value,
                f"positions[{i}].sign (model q{i + 1}, driver joint {entry.joint!r}) looks "
                f"flipped: with sign = {-entry.sign:+g} the model's tip matches measured_cp to "
                f"{value * 1e3:.2f} mm (now {rms * 1e3:.2f} mm)",
            )
        )
    n = interface.n_joints
    for i, entry in enumerate(interface.positions):
        unit = np.zeros(n)
        unit[i] = 1.0

        def cost(d: float, unit: np.ndarray = unit) -> float:
            return residual_of(interface, d * unit)

        best = minimize_scalar(cost, bounds=(-np.pi, np.pi), method="bounded")
        delta = float(best.x)
        value = float(best.fun)
        candidates.append(
            (
                value,
                f"positions[{i}].offset_rad (model q{i + 1}, driver joint {entry.joint!r}) "
                f"looks wrong by {delta:+.4f} rad: with offset_rad = "
                f"{entry.offset_rad + delta:.4f} the model's tip matches measured_cp to "
                f"{value * 1e3:.2f} mm (now {rms * 1e3:.2f} mm)",
            )
        )
    candidates.sort(key=lambda c: c[0])
    explained = [message for value, message in candidates if value <= tolerance_m]
    if explained:
        return CheckResult(False, rms, (explained[0],), offset)
    return CheckResult(
        False,
        rms,
        (
            f"the model's tip is {rms * 1e3:.2f} mm from measured_cp and no single sign or "
            "offset in 'positions' explains it (check position_coupling, the joint names "
            "and the driver's joint-scales / joint-offsets)",
        ),
        offset,
    )


def check_efforts(
    interface: DriverInterface,
    tip_jacobian: TipJacobian,
    names: Sequence[str],
    positions: np.ndarray,
    efforts: np.ndarray,
    measured_cf_n: np.ndarray,
    tolerance: float = 0.05,
) -> CheckResult:
    """Compare ``to_model``'s torques with ``J(q)^T F`` of the driver's commanded force.

    For a driver that renders a Cartesian force ``F`` (``measured_cf``, N, in its base frame,
    the force on the user's hand) as motor torques, ``tau = J(q)^T base_rotation F``.
    Per joint, the least-squares ratio of the two must be 1 within ``tolerance``; a common
    ratio of one unit to another names ``effort_unit``, a ratio of -1 the entry's sign.
    The samples need forces that move each joint (not all zero).
    """
    x = _samples(names, positions, "positions")
    e = _samples(names, efforts, "efforts")
    force = np.asarray(measured_cf_n, dtype=float)
    if force.shape != (x.shape[0], 3):
        raise DataError(f"measured_cf: expected ({x.shape[0]}, 3) values, got {force.shape}")
    q, tau = interface.to_model(names, x, e)
    assert tau is not None  # efforts given
    expected = np.array(
        [tip_jacobian(qi).T @ (interface.rotation @ fi) for qi, fi in zip(q, force, strict=True)]
    )
    power = np.sum(expected**2, axis=0)
    if np.any(power <= 0):
        j = int(np.argmin(power))
        raise DataError(f"measured_cf: the forces do not move model joint q{j + 1}")
    ratio = np.sum(tau * expected, axis=0) / power
    fit = np.sqrt(np.mean((tau - expected) ** 2))
    bad = np.abs(ratio - 1.0) > tolerance
    if not np.any(bad):
        return CheckResult(True, float(fit), ())
    findings: list[str] = []
    if np.all(bad) and np.all(ratio > 0):
        common = float(np.exp(np.mean(np.log(ratio))))
        for unit, factor in EFFORT_UNITS.items():
            if abs(common * factor / interface.unit_scale - 1.0) <= tolerance:
                findings.append(
                    f"effort_unit looks wrong: the torques are {common:.4g} x J^T F; with "
                    f"effort_unit = {unit!r} (not {interface.effort_unit!r}) they match"
                )
                break
        else:
            findings.append(
                f"effort_unit or the unit of measured_cf looks wrong: every joint's torque "
                f"is {common:.4g} x J^T F"
            )
        return CheckResult(False, float(fit), tuple(findings))
    for i in np.flatnonzero(bad):
        entry = interface.efforts[i]
        if abs(ratio[i] + 1.0) <= tolerance:
            findings.append(
                f"efforts[{i}].sign (model tau{i + 1}, driver joint {entry.joint!r}) looks "
                f"flipped: the torque is {ratio[i]:.3f} x (J^T F){i + 1}"
            )
        else:
            findings.append(
                f"efforts[{i}] (model tau{i + 1}, driver joint {entry.joint!r}): the torque is "
                f"{ratio[i]:.3f} x (J^T F){i + 1} (check effort_coupling and the joint name)"
            )
    return CheckResult(False, float(fit), tuple(findings))
