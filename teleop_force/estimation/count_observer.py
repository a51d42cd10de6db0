"""The encoder count observer: joint angles between the counts, from the model and the torques.

An encoder reads the angle to within one count ``c`` (a fraction of a milliradian on the
Omni). Every estimator of the contact force differentiates the angle (the momentum ``M qd``,
the friction's velocity), so the counts are what bounds its bandwidth: fed the plant's true
angles, the default estimator errs 9 % less on plant family one and 32 % less on family two,
the best estimator 27 % and 44 % less than the best on the counts
(docs/accuracy/low_speed.md). This observer gives them angles that move between the counts,
the way the arm does.

Per joint it keeps the angle ``q``, the momentum ``p`` and a disturbance torque ``d`` (the
external torque and what the model lacks), and per sample (``dt``):

1. **Predicts** with the identified model in momentum form (motor coordinates, springs and
   rotor inertia included), the commanded torque of the last sample and the model's
   Coulomb-viscous term table at its own velocity ``v = M(q)^-1 p``::

       p += dt (tau - g(q) + C(q, v)^T v - springs - f(v) - d);   q += dt M(q)^-1 p

2. **Corrects only where the count says the prediction is wrong**: the angle is clipped to
   the count's interval ``[reading - c/2, reading + c/2]``; the clip ``e`` (0 inside) moves
   the velocity and the disturbance::

       q += e;   p += k_v M e / dt;   d -= k_d M e / dt^2

Inside the interval nothing is measured, so nothing is corrected: the model carries the angle.
``k_v = 0.1``, ``k_d = 0.01`` were chosen on plant family one, seeds 1-3, and held out on
family two (docs/accuracy/low_speed.md, tenth session). Where a reading is floored instead of
rounded the interval is shifted by half a count: a constant offset of the angles, which the
velocity and the force do not see.

The count ``c`` per joint is the model's (identification measures it:
:mod:`~teleop_force.identification.encoder_count`); the batch estimator measures it on the
recording it estimates when the model has none. A stream starts the observer at its first
reading (momentum 0, the disturbance balancing the model at rest), and so does a prediction
:data:`RESYNC_COUNTS` counts outside its reading, or not finite: a glitch, a gap or torques
the model cannot follow are dropped, not corrected.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from teleop_force.compiled import njit_cached, view_2d
from teleop_force.estimation.kernels import (
    STEP_NON_FINITE,
    STEP_OK,
    STEP_TIME_NOT_INCREASING,
    ModelTerms,
    linear_map_into,
    momenta_to_motor_into,
)
from teleop_force.estimation.rigid_chain import (
    ChainTables,
    chain_kinematics_into,
    chain_momentum_into,
    chain_work_size,
)
from teleop_force.friction.terms import linear_friction_torque_into
from teleop_force.packed_tables import pack, slot_1d, slot_2d, slot_3d

#: The velocity gain ``k_v`` (module docstring), chosen on plant family one, seeds 1-3.
COUNT_VELOCITY_GAIN = 0.1
#: The disturbance gain ``k_d`` (module docstring), chosen with it.
COUNT_TORQUE_GAIN = 0.01
#: A prediction this many counts outside its reading is dropped: the observer resyncs there.
RESYNC_COUNTS = 32.0
#: The observer's state: ``[started, t_prev, q (n), p (n), d (n), v (n), tau_prev (n)]``.
STATE_HEAD = 2


@njit_cached()
def state_size(n: int) -> int:  # pragma: no cover - compiled
    """Floats of the observer's state for ``n`` joints (zeros: a stream not started)."""
    return STATE_HEAD + 5 * n


@njit_cached()
def scratch_size(n: int, n_model: int, n_bodies: int) -> int:  # pragma: no cover - compiled
    """Floats of the step's scratch (matrices, model-coordinate vectors, the chain's work)."""
    return 2 * n * n + 5 * n + 4 * n_model + 3 * n + chain_work_size(n_bodies)


@njit_cached()
def _solve_into(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """``out = a^-1 b`` by Gaussian elimination with partial pivoting (``a``, ``b`` destroyed)."""
    n = b.size
    for c in range(n):
        pivot = c
        for r in range(c + 1, n):
            if abs(a[r, c]) > abs(a[pivot, c]):
                pivot = r
        if pivot != c:
            for k in range(n):
                a[c, k], a[pivot, k] = a[pivot, k], a[c, k]
            b[c], b[pivot] = b[pivot], b[c]
        for r in range(c + 1, n):
            factor = a[r, c] / a[c, c]
            for k in range(c, n):
                a[r, k] -= factor * a[c, k]
            b[r] -= factor * b[c]
    for r in range(n - 1, -1, -1):
        value = b[r]
        for k in range(r + 1, n):
            value -= a[r, k] * out[k]
        out[r] = value / a[r, r]


@njit_cached()
def _mass_and_other_into(
    q: np.ndarray,
    v: np.ndarray,
    tables: tuple[Any, ...],
    scratch: np.ndarray,
    mass: np.ndarray,
    other: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``M(q)`` and ``g - C^T v + springs`` in motor coordinates (rotor inertia included).

    The compiled chain's model-coordinate terms mapped to the motors as the estimator's step
    maps them (:func:`~teleop_force.estimation.kernels.momenta_to_motor_into`); column ``j`` of
    ``M`` is the momentum of a unit velocity of motor ``j``.
    """
    parent, kind, axis, rotation, translation, velocity_index = tables[3:9]
    link_mass, com, inertia, gravity, coupling, rotor, springs = tables[9:16]
    n_model, n = coupling.shape
    q_model = scratch[0:n_model]
    v_model = scratch[n_model : 2 * n_model]
    momenta = view_2d(scratch, 2 * n_model, 2, n_model)
    unit = scratch[4 * n_model : 4 * n_model + n]
    momentum = scratch[4 * n_model + n : 4 * n_model + 2 * n]
    discarded = scratch[4 * n_model + 2 * n : 4 * n_model + 3 * n]
    work = scratch[4 * n_model + 3 * n :]
    linear_map_into(coupling, q, q_model)
    chain_kinematics_into(q_model, parent, kind, axis, rotation, translation, velocity_index, work)
    for j in range(-1, n):  # the velocity v, then each motor's unit velocity
        if j >= 0:
            unit[:] = 0.0
            unit[j] = 1.0
        velocity = v if j < 0 else unit
        linear_map_into(coupling, velocity, v_model)
        chain_momentum_into(
            v_model, parent, velocity_index, link_mass, com, inertia, gravity, work, momenta[0],
            momenta[1],
        )  # fmt: skip
        if j < 0:
            momenta_to_motor_into(q, v, momenta, coupling, rotor, springs, momentum, other)
        else:
            momenta_to_motor_into(q, unit, momenta, coupling, rotor, springs, momentum, discarded)
            for i in range(n):  # a loop, not a slice: numba's slice copy costs seconds to compile
                mass[i, j] = momentum[i]


#: Slots of the packed tables (:func:`observer_tables`): floats, then ints.
(
    _COUNT, _GAINS, _AXIS, _ROTATION, _TRANSLATION, _LINK_MASS, _COM, _INERTIA, _GRAVITY,
    _COUPLING, _ROTOR, _SPRINGS, _ROWS, _REACH, _FRICTION, _PARENT, _KIND, _VELOCITY_INDEX,
) = range(18)  # fmt: skip


@njit_cached(inline="always")
def _unpack(floats: np.ndarray, ints: np.ndarray) -> tuple[Any, ...]:  # pragma: no cover
    """Return the tables as views: counts, gains, chain, body, the friction's term table."""
    gains = slot_1d(floats, ints, _GAINS)
    return (
        slot_1d(floats, ints, _COUNT), gains[0], gains[1], slot_1d(ints, ints, _PARENT),
        slot_1d(ints, ints, _KIND), slot_2d(floats, ints, _AXIS),
        slot_3d(floats, ints, _ROTATION), slot_2d(floats, ints, _TRANSLATION),
        slot_1d(ints, ints, _VELOCITY_INDEX), slot_1d(floats, ints, _LINK_MASS),
        slot_2d(floats, ints, _COM), slot_3d(floats, ints, _INERTIA),
        slot_1d(floats, ints, _GRAVITY), slot_2d(floats, ints, _COUPLING),
        slot_1d(floats, ints, _ROTOR), slot_2d(floats, ints, _SPRINGS),
        slot_2d(floats, ints, _ROWS), slot_2d(floats, ints, _REACH),
        slot_1d(floats, ints, _FRICTION),
    )  # fmt: skip


@njit_cached()
def count_observer_step(
    state: np.ndarray,
    t_s: float,
    q_count: np.ndarray,
    tau: np.ndarray,
    floats: np.ndarray,
    ints: np.ndarray,
    scratch: np.ndarray,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Advance the observer by one reading; its angles into ``out`` (module docstring).

    ``floats``, ``ints``, ``scratch``: :func:`observer_tables`. ``q_count`` and ``tau``: arrays
    or tuples of floats. Returns ``STEP_OK``, or ``STEP_NON_FINITE`` /
    ``STEP_TIME_NOT_INCREASING`` with the state untouched (ValueError for a reading of another
    number of joints). A zeroed state starts a stream here.
    """
    tables = _unpack(floats, ints)
    count_rad, velocity_gain, torque_gain = tables[0], tables[1], tables[2]
    n = count_rad.size
    if len(q_count) != n or len(tau) != n:
        raise ValueError("wrong number of joint angles or torques")
    if not math.isfinite(t_s):
        return STEP_NON_FINITE
    for j in range(n):
        if not (math.isfinite(q_count[j]) and math.isfinite(tau[j])):
            return STEP_NON_FINITE
    started = state[0] != 0.0
    if started and not t_s > state[1]:
        return STEP_TIME_NOT_INCREASING
    h = t_s - state[1]
    q = state[STATE_HEAD : STATE_HEAD + n]
    p = state[STATE_HEAD + n : STATE_HEAD + 2 * n]
    d = state[STATE_HEAD + 2 * n : STATE_HEAD + 3 * n]
    v = state[STATE_HEAD + 3 * n : STATE_HEAD + 4 * n]
    tau_prev = state[STATE_HEAD + 4 * n : STATE_HEAD + 5 * n]
    mass = view_2d(scratch, 0, n, n)
    lu = view_2d(scratch, n * n, n, n)
    other = scratch[2 * n * n : 2 * n * n + n]
    friction = scratch[2 * n * n + n : 2 * n * n + 2 * n]
    error = scratch[2 * n * n + 2 * n : 2 * n * n + 3 * n]
    rhs = scratch[2 * n * n + 3 * n : 2 * n * n + 4 * n]
    correction = scratch[2 * n * n + 4 * n : 2 * n * n + 5 * n]
    chain = scratch[2 * n * n + 5 * n :]
    if started:
        _terms_at(q, v, tables, chain, mass, other, friction)
        started = _predict_and_correct(
            h, q_count, count_rad, velocity_gain, torque_gain, q, p, d, v, tau_prev, mass, lu,
            other, friction, error, rhs, correction,
        )  # fmt: skip
    if not started:  # a stream's first reading, or a resync
        for j in range(n):
            q[j] = q_count[j]
            p[j] = 0.0
            v[j] = 0.0
        _terms_at(q, v, tables, chain, mass, other, friction)
        for j in range(n):
            d[j] = tau[j] - other[j] - friction[j]
    for j in range(n):
        tau_prev[j] = tau[j]
        out[j] = q[j]
    state[0] = 1.0
    state[1] = t_s
    return STEP_OK


@njit_cached()
def _terms_at(
    q: np.ndarray,
    v: np.ndarray,
    tables: tuple[Any, ...],
    chain: np.ndarray,
    mass: np.ndarray,
    other: np.ndarray,
    friction: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``M(q)``, ``g - C^T v + springs`` and the term table's friction at ``q``, ``v``."""
    _mass_and_other_into(q, v, tables, chain, mass, other)
    rows, reach, friction_parameters = tables[16:19]
    friction[:] = 0.0
    linear_friction_torque_into(v, rows, reach, friction_parameters, friction)


@njit_cached()
def _predict_and_correct(
    h: float,
    q_count: np.ndarray,
    count_rad: np.ndarray,
    velocity_gain: float,
    torque_gain: float,
    q: np.ndarray,
    p: np.ndarray,
    d: np.ndarray,
    v: np.ndarray,
    tau_prev: np.ndarray,
    mass: np.ndarray,
    lu: np.ndarray,
    other: np.ndarray,
    friction: np.ndarray,
    error: np.ndarray,
    rhs: np.ndarray,
    correction: np.ndarray,
) -> bool:  # pragma: no cover - compiled
    """Predict over ``h`` and correct (module docstring); False: resync at this reading.

    A prediction more than :data:`RESYNC_COUNTS` counts outside its reading, or not finite (a
    glitch of the encoder, a gap in the stream, torques the model cannot follow), is not
    corrected but dropped: the observer starts again from the reading.
    """
    n = q.size
    for j in range(n):
        p[j] += h * (tau_prev[j] - other[j] - friction[j] - d[j])
    _velocity_into(mass, p, lu, rhs, v)
    clipped = False
    for j in range(n):
        q[j] += h * v[j]
        half = 0.5 * count_rad[j]
        if q[j] > q_count[j] + half:
            error[j] = q_count[j] + half - q[j]
            clipped = True
        elif q[j] < q_count[j] - half:
            error[j] = q_count[j] - half - q[j]
            clipped = True
        elif q[j] == q[j]:
            error[j] = 0.0
        else:  # NaN
            return False
        if abs(error[j]) > RESYNC_COUNTS * count_rad[j]:
            return False
    if clipped:
        for a in range(n):
            w = 0.0
            for b in range(n):
                w += mass[a, b] * error[b]
            correction[a] = w
        for j in range(n):
            q[j] += error[j]
            p[j] += velocity_gain * correction[j] / h
            d[j] -= torque_gain * correction[j] / (h * h)
        _velocity_into(mass, p, lu, rhs, v)
    for j in range(n):
        if not (math.isfinite(p[j]) and math.isfinite(d[j]) and math.isfinite(v[j])):
            return False
    return True


@njit_cached()
def _velocity_into(
    mass: np.ndarray, p: np.ndarray, lu: np.ndarray, rhs: np.ndarray, v: np.ndarray
) -> None:  # pragma: no cover - compiled
    """``v = M^-1 p`` (``M`` kept)."""
    n = p.size
    for i in range(n):  # loops, not slices: numba's slice copy costs seconds to compile
        rhs[i] = p[i]
        for k in range(n):
            lu[i, k] = mass[i, k]
    _solve_into(lu, rhs, v)


@njit_cached()
def observe_counts(
    t_s: np.ndarray,
    q_count: np.ndarray,
    tau: np.ndarray,
    starts: np.ndarray,
    floats: np.ndarray,
    ints: np.ndarray,
    scratch: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """Return the observed angles of every sample, a stream beginning at each set ``starts``.

    :func:`count_observer_step` over the samples (the caller has checked them).
    """
    n_samples, n = q_count.shape
    out = np.empty((n_samples, n))
    state = np.zeros(state_size(n))
    for k in range(n_samples):
        if starts[k]:
            state[:] = 0.0
        count_observer_step(state, t_s[k], q_count[k], tau[k], floats, ints, scratch, out[k])
    return out


def observer_tables(
    count_rad: np.ndarray,
    chain: ChainTables,
    coupling: np.ndarray,
    rotor: np.ndarray,
    springs: np.ndarray,
    terms: ModelTerms,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the observer's constant tables packed (floats, ints) and its scratch.

    Counts, gains, the kinematic chain, the body in motor coordinates and the model's
    Coulomb-viscous terms (:meth:`~teleop_force.estimation.kernels.ModelTerms.term_table`)
    (:mod:`~teleop_force.packed_tables`: one crossing into compiled code costs ~70 ns per
    array argument): what :func:`count_observer_step` and :func:`observe_counts` take after
    their samples.
    """
    rows, reach, parameters = terms.term_table()
    floats, ints = pack(
        [
            count_rad, np.array([COUNT_VELOCITY_GAIN, COUNT_TORQUE_GAIN]), chain.axis,
            chain.rotation, chain.translation, chain.mass, chain.com, chain.inertia,
            chain.gravity, coupling, rotor, np.reshape(springs, (-1, 3)), rows, reach,
            parameters,
        ],
        [chain.parent, chain.kind, chain.velocity_index],
    )  # fmt: skip
    n_model, n = np.shape(coupling)
    return floats, ints, np.zeros(scratch_size(n, n_model, chain.n_bodies))
