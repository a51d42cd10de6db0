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
