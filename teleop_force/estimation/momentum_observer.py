"""The generalised-momentum observer: the external torque as the residual of the momentum balance.

The field's standard alternative to filtering the dynamics (De Luca and Mattone 2003): with
the generalised momentum ``p = M(q) qd`` the model reads, in this project's sign (the torque
the motors exert beyond the model, on the environment, as ``tau_ext`` of the filter)::

    d/dt p = tau - beta(q, qd) - tau_f(qd) - tau_ext,   beta = g - C^T qd + tau_spring

and the observer integrates the model's momentum and feeds back the mismatch::

    r_k         = K_k (p_hat_k - p_k)
    p_hat_{k+1} = p_hat_k + dt (tau_k - beta_k - tau_f,k - r_k)

so ``r`` follows ``tau_ext`` through a first-order lag of bandwidth ``K`` (rad/s): no
accelerations, one parameter. The per-step gain is ``K_k = (1 - exp(-K dt_k)) / dt_k``
(``K`` to first order in ``K dt``), which makes the discrete response exactly first order
with time constant ``1 / K``, the discretisation of the filter ``L``; plain ``K`` would
shorten it by ``K dt / 2`` (2.5 % at 8 Hz and 1 kHz).

In continuous time the observer with bandwidth ``K`` equals the filtered dynamics with a
first-order filter at ``K``; they differ in the discretisation and in that the observer's
bandwidth is a parameter of its own (:class:`~teleop_force.identification.filtered_regressor.
FilterConfig`'s ``observer_hz``), independent of the ``L`` the model was identified with.

The residual may then pass a second-order Butterworth low-pass (:func:`butterworth_step_into`,
``FilterConfig.observer_output_hz``, an option): with the observer fast (e.g. 400 Hz, nearly
the momentum balance itself) the Butterworth does the filtering, with less lag than
first-order stages for the same rejection of the encoder's noise.

:func:`observer_update_into` is one sample of one stream, on preallocated arrays, so that any
compiled step (the streaming estimator's :func:`~teleop_force.estimation.kernels.finish_step`,
the batch loop) calls the same definition.
"""

from __future__ import annotations

import math

import numpy as np

from teleop_force.compiled import njit_cached


@njit_cached()
def observer_gain(omega_rad_s: float, dt_s: float) -> float:  # pragma: no cover - compiled
    """Per-step gain ``(1 - exp(-K dt)) / dt`` of bandwidth ``K = omega_rad_s``."""
    return -math.expm1(-omega_rad_s * dt_s) / dt_s


@njit_cached()
def observer_update_into(
    momentum: np.ndarray,
    tau: np.ndarray,
    beta: np.ndarray,
    friction: np.ndarray,
    dt_s: float,
    omega_rad_s: float,
    lag: int,
    first: bool,
    p_hat: np.ndarray,
    drive: np.ndarray,
    residual: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """One observer sample: advance ``p_hat`` over ``dt_s``, write ``residual``, the next drive.

    ``momentum`` is ``p_k`` (n), ``tau`` the (pre-filtered) motor torque of this sample, ``beta``
    the model's non-inertial rigid-body torque ``g - C^T qd + springs``, ``friction`` friction
    + offsets + effects. ``p_hat`` and ``drive`` (n each) are the observer's state: the
    estimated momentum and ``d/dt p_hat`` of the previous sample (its torque included for
    ``lag`` 1: the torque of ``k-1`` acts over ``[k-1, k]``; for ``lag`` 0 the torque of
    ``k`` is added here). ``first``: a stream's first sample (``p_hat = p``, residual 0;
    ``dt_s`` unused). ``residual`` (n) receives ``r_k``, the external torque.
    """
    n = momentum.size
    gain = 0.0 if first else observer_gain(omega_rad_s, dt_s)
    for j in range(n):
        if first:
            p_hat[j] = momentum[j]
        else:
            rate = drive[j]
            if lag == 0:
                rate += tau[j]
            p_hat[j] += dt_s * rate
        r = gain * (p_hat[j] - momentum[j])
        residual[j] = r
        rate = -beta[j] - friction[j] - r
        if lag != 0:
            rate += tau[j]
        drive[j] = rate


#: Largest half-angle ``omega dt / 2`` the filter integrates over; beyond it, it has settled.
_MAX_HALF_ANGLE_RAD = 1.5
#: Floats of the output filter's state per entry: its output, the output's rate, its input.
BUTTERWORTH_STATES = 3


@njit_cached()
def butterworth_step_into(
    values: np.ndarray, state: np.ndarray, omega_rad_s: float, dt_s: float, first: bool
) -> None:  # pragma: no cover - compiled
    """One sample of a second-order Butterworth low-pass at ``omega_rad_s`` over ``values``.

    In place, per entry: ``y'' = w^2 (x - y) - sqrt(2) w y'`` integrated by the trapezoidal
    rule over ``dt_s`` with ``w`` pre-warped for it (``(2 / dt) tan(omega dt / 2)``): at a
    constant ``dt`` this is the bilinear transform, ``scipy.signal.butter(2, f, fs=1 / dt)``.
    Its state is physical (``y``, ``y'`` and the last input ``x`` of entry ``j`` at
    ``state[3 j : 3 j + 3]``, :data:`BUTTERWORTH_STATES` per entry), so an irregular ``dt``
    never makes it jump. A gap with ``omega dt / 2`` beyond 1.5 rad (12 ms at 40 Hz; the
    transform folds back at pi / 2 and the trapezoid rings on so long a step) is one the
    filter has settled over: the sample passes unchanged and the filter rests there, as at a
    stream's first sample (``first``, ``dt_s`` unused).
    """
    n = values.size
    if first or 0.5 * omega_rad_s * dt_s > _MAX_HALF_ANGLE_RAD:
        for j in range(n):
            state[3 * j] = values[j]
            state[3 * j + 1] = 0.0
            state[3 * j + 2] = values[j]
        return
    h = 0.5 * dt_s
    w = math.tan(0.5 * omega_rad_s * dt_s) / h
    a = w * w * h
    b = 1.0 + math.sqrt(2.0) * w * h
    det = b + a * h
    for j in range(n):
        y = state[3 * j]
        v = state[3 * j + 1]
        x = values[j]
        r1 = y + h * v
        r2 = v - a * y - (b - 1.0) * v + a * (state[3 * j + 2] + x)
        y_next = (b * r1 + h * r2) / det
        state[3 * j] = y_next
        state[3 * j + 1] = (r2 - a * r1) / det
        state[3 * j + 2] = x
        values[j] = y_next
