"""The friction model's terms, each defined once (numba): Coulomb-viscous, Mexican hat, trust.

Every term is one compiled function on floats and small arrays; the batch methods of the
friction models call it over samples, the streaming estimator once per sample
(:mod:`teleop_force.estimation.kernels`), and other compiled code may call it directly:

* :func:`coulomb_viscous`: ``a_c sgn(w) + a_v w`` of one velocity ``w``; the velocity of a
  term is a linear form of the joint velocities (:func:`term_velocity`): ``qd_j`` for
  :class:`~teleop_force.friction.coulomb_viscous.CoulombViscous`, ``qd_a - qd_b`` for the
  coupled terms, a coupling row for model-coordinate friction. A *term table* lists them:
  ``rows`` (T, n) the velocity forms, ``reach`` (T, n) the motor torque per unit of the term's
  torque, ``parameters`` (2 T,) ``[a_c, a_v]`` per term (:func:`linear_friction_torque_into`);
* :func:`mexican_hat_r2`: the wavelet ``amp (1 - r2) exp(-r2 / 2)`` of a squared normalised
  distance ``r2`` (its ``exp`` inline, so that loops over wavelets vectorise);
* :func:`grid_density` and :func:`coverage_trust`: a coverage grid's smoothed density,
  multilinear between cell centres and 0 one cell outside (as ``scipy.ndimage.map_coordinates``
  with ``order=1, mode="grid-constant"``), and the smoothstep trust ramp over it;
* :func:`sticking_update_into`: the sticking (Dahl) state of a term, which replaces its
  ``sgn(w)`` when the model has a transition angle: it follows the term's angle (the path,
  not the time), reaches ``sgn`` within a few transition angles of motion and holds at rest;
* :func:`standstill_factor`: the standstill dead band, a ramp of the friction torque (and
  of found effects' direction factor) to 0 while every joint is slower than a band (the
  Coulomb sign is unknown at rest).
"""

from __future__ import annotations

import math

import numpy as np

from teleop_force.compiled import njit_cached

_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10

# -- Coulomb + viscous -------------------------------------------------------------------------


@njit_cached()
def sign(x: float) -> float:  # pragma: no cover - compiled
    """``np.sign`` of a float (NaN stays NaN)."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x * 0.0


@njit_cached()
def coulomb_viscous(w: float, a_c: float, a_v: float) -> float:  # pragma: no cover - compiled
    """Coulomb + viscous friction ``a_c sgn(w) + a_v w`` of the velocity ``w``."""
    return a_c * sign(w) + a_v * w


@njit_cached()
def term_velocity(row: np.ndarray, qd: np.ndarray) -> float:  # pragma: no cover - compiled
    """``row @ qd`` over the nonzero entries of ``row`` (``qd_a - qd_b`` exactly for ±1 rows)."""
    w = 0.0
    for i in range(row.size):
        r = row[i]
        if r != 0.0:  # ±1 rows multiply exactly; zeros are skipped, so a NaN stays put
            w += r * qd[i]
    return w


@njit_cached()
def add_weighted_into(
    value: float, weights: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover
    """``out += weights * value`` over the nonzero weights (a term's reach on the joints)."""
    for j in range(out.size):
        weight = weights[j]
        if weight != 0.0:
            out[j] += weight * value


@njit_cached()
def linear_friction_torque_into(
    qd: np.ndarray, rows: np.ndarray, reach: np.ndarray, parameters: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Add the torque of every term of a term table at one sample ``qd`` (n,) to ``out`` (n,)."""
    for t in range(rows.shape[0]):
        f = coulomb_viscous(term_velocity(rows[t], qd), parameters[2 * t], parameters[2 * t + 1])
        add_weighted_into(f, reach[t], out)


@njit_cached()
def linear_friction_torque(
    qd: np.ndarray, rows: np.ndarray, reach: np.ndarray, parameters: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """Torque of a term table at every sample: ``qd`` (N, n) -> (N, n)."""
    out = np.zeros((qd.shape[0], reach.shape[1]))
    for k in range(qd.shape[0]):
        linear_friction_torque_into(qd[k], rows, reach, parameters, out[k])
    return out


@njit_cached()
def linear_friction_basis(
    qd: np.ndarray, rows: np.ndarray, first: int, stop: int
) -> np.ndarray:  # pragma: no cover - compiled
    """Columns ``[sgn(w_t), w_t]`` of the terms ``first..stop-1``: (N, n) -> (N, 2 (stop - first)).

    ``coulomb_viscous(w, a_c, a_v) = [sgn(w), w] @ [a_c, a_v]``: the regressor of the terms.
    """
    out = np.empty((qd.shape[0], 2 * (stop - first)))
    for k in range(qd.shape[0]):
        for t in range(first, stop):
            w = term_velocity(rows[t], qd[k])
            out[k, 2 * (t - first)] = sign(w)
            out[k, 2 * (t - first) + 1] = w
    return out


# -- the sticking (Dahl) state of the Coulomb terms ----------------------------------------------


@njit_cached()
def dahl_step(z: float, dpsi: float, inv_transition: float) -> float:  # pragma: no cover
    """Return the Dahl state after the angle moved by ``dpsi``: ``dz/dpsi = (1 - z sgn) / phi``.

    Solved exactly over the step (``z -> sgn(dpsi)`` as ``1 - exp(-|dpsi| / phi)``, with
    ``expm1`` so that tiny steps still move it), so it stays in [-1, 1] at any sample rate;
    ``inv_transition`` is ``1 / phi`` [1/rad].
    """
    if dpsi > 0.0:
        return z - (1.0 - z) * math.expm1(-dpsi * inv_transition)
    if dpsi < 0.0:
        return z + (1.0 + z) * math.expm1(dpsi * inv_transition)
    return z


@njit_cached()
def sticking_update_into(
    q: np.ndarray, rows: np.ndarray, inv_transition: float, state: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Advance the sticking state of a term table to the angles ``q`` (n,) of the next sample.

    ``state`` (1 + 2 T): ``[started, angle_t..., z_t...]``, the angle of a term being its row
    applied to ``q`` (as its velocity is to ``qd``); all zeros begins a stream at ``z = 0``.
    """
    terms = rows.shape[0]
    if state[0] == 0.0:
        for t in range(terms):
            state[1 + t] = term_velocity(rows[t], q)
            state[1 + terms + t] = 0.0
        state[0] = 1.0
        return
    for t in range(terms):
        angle = term_velocity(rows[t], q)
        state[1 + terms + t] = dahl_step(state[1 + terms + t], angle - state[1 + t], inv_transition)
        state[1 + t] = angle


@njit_cached()
def sticking_states_into(
    q: np.ndarray, rows: np.ndarray, inv_transition: float, starts: np.ndarray, state: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """Return the Dahl state of every term at every sample: ``q`` (N, n) -> (N, T).

    ``state`` (1 + 2 T, :func:`sticking_update_into`) is carried over from the previous call
    and left at the last sample; a stream begins (``z = 0``) wherever ``starts`` (N, bool) is
    set.
    """
    terms = rows.shape[0]
    out = np.empty((q.shape[0], terms))
    for k in range(q.shape[0]):
        if starts[k]:
            state[0] = 0.0
        sticking_update_into(q[k], rows, inv_transition, state)
        for t in range(terms):
            out[k, t] = state[1 + terms + t]
    return out


@njit_cached()
def sticking_states(
    q: np.ndarray, rows: np.ndarray, inv_transition: float, starts: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`sticking_states_into` from a new stream at sample 0: ``q`` (N, n) -> (N, T)."""
    return sticking_states_into(q, rows, inv_transition, starts, np.zeros(1 + 2 * rows.shape[0]))


@njit_cached()
def sticking_friction_torque(
    qd: np.ndarray, rows: np.ndarray, reach: np.ndarray, parameters: np.ndarray, z: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """Torque of a term table with its sticking states ``z`` (N, T) at every sample (N, n)."""
    out = np.zeros((qd.shape[0], reach.shape[1]))
    for k in range(qd.shape[0]):
        sticking_friction_torque_into(qd[k], rows, reach, parameters, z[k], out[k])
    return out


@njit_cached()
def sticking_friction_torque_into(
    qd: np.ndarray,
    rows: np.ndarray,
    reach: np.ndarray,
    parameters: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """:func:`linear_friction_torque_into` with each term's ``sgn(w_t)`` replaced by ``z_t``."""
    for t in range(rows.shape[0]):
        f = parameters[2 * t] * z[t] + parameters[2 * t + 1] * term_velocity(rows[t], qd)
        add_weighted_into(f, reach[t], out)


# -- the standstill dead band ----------------------------------------------------------------------


@njit_cached()
def standstill_factor(qd: np.ndarray, band_rad_s: float) -> float:  # pragma: no cover - compiled
    """Scale of the friction torque at the joint velocities ``qd``: a ramp to 0 at standstill.

    ``max_j |qd_j| / band_rad_s`` while every joint is slower than ``band_rad_s``, else 1
    (also for ``band_rad_s <= 0``, no dead band, and for a NaN velocity). At rest under load
    the sign of the Coulomb term is unknown; the ramp keeps it from becoming a phantom force.
    """
    if not band_rad_s > 0.0:
        return 1.0
    fastest = 0.0
    for j in range(qd.size):
        speed = abs(qd[j])
        if not speed < band_rad_s:
            return 1.0
        if speed > fastest:
            fastest = speed
    return fastest / band_rad_s


@njit_cached()
def standstill_scale_into(
    qd: np.ndarray, band_rad_s: float, torque: np.ndarray
) -> None:  # pragma: no cover - compiled
    """``torque *= standstill_factor(qd, band_rad_s)`` in place (one sample's friction)."""
    factor = standstill_factor(qd, band_rad_s)
    if factor != 1.0:
        for j in range(torque.size):
            torque[j] *= factor


@njit_cached()
def standstill_factors(qd: np.ndarray, band_rad_s: float) -> np.ndarray:  # pragma: no cover
    """:func:`standstill_factor` of every sample: ``qd`` (N, n) -> (N,)."""
    out = np.empty(qd.shape[0])
    for k in range(qd.shape[0]):
        out[k] = standstill_factor(qd[k], band_rad_s)
    return out


# -- the Mexican hat -----------------------------------------------------------------------------


@njit_cached(fastmath={"contract"})
def exp_inline(h: float) -> float:  # pragma: no cover - compiled
    """``exp(h)`` for ``h <= 0`` (clamped at -708), inline so that loops vectorise.

    ``exp(h) = 2^n exp(r)``, ``n = round(h / ln 2)``, ``|r| <= ln(2) / 2`` with a two-part
    ``ln 2``, ``exp(r)`` by its Taylor polynomial of degree 13 (truncation < 2.2e-16 relative),
    ``2^n`` built from its exponent bits (LLVM has no vector ``exp`` without Intel's SVML).
    """
    h = max(h, -708.0)
    fn = math.floor(h * _LOG2E + 0.5)
    r = (h - fn * _LN2_HI) - fn * _LN2_LO
    q = 1.0 / 6227020800.0
    q = q * r + 1.0 / 479001600.0
    q = q * r + 1.0 / 39916800.0
    q = q * r + 1.0 / 3628800.0
    q = q * r + 1.0 / 362880.0
    q = q * r + 1.0 / 40320.0
    q = q * r + 1.0 / 5040.0
    q = q * r + 1.0 / 720.0
    q = q * r + 1.0 / 120.0
    q = q * r + 1.0 / 24.0
    q = q * r + 1.0 / 6.0
    q = q * r + 0.5
    q = q * r + 1.0
    q = q * r + 1.0
    two_n = np.int64((np.int64(fn) + 1023) << 52).view(np.float64)
    return q * two_n


@njit_cached(fastmath={"contract"})
def mexican_hat_r2(r2: float, amplitude: float) -> float:  # pragma: no cover - compiled
    """Return the Mexican hat ``amplitude (1 - r2) exp(-r2 / 2)`` at squared distance ``r2``."""
    return amplitude * (1.0 - r2) * exp_inline(-0.5 * r2)


@njit_cached(fastmath={"contract"})
def mexican_hat_values(r2: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`mexican_hat_r2` (amplitude 1) of every entry of a 1-D array."""
    out = np.empty(r2.size)
    for k in range(r2.size):
        out[k] = mexican_hat_r2(r2[k], 1.0)
    return out


@njit_cached(fastmath={"contract"})
def wavelet_block(
    x: np.ndarray, centre_scaled: np.ndarray, inv_scale: np.ndarray, amplitude: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """Wavelets of one joint network at every sample: ``x`` (N, d) -> (N, P).

    Wavelet ``p`` is ``mexican_hat_r2(|x inv_scale[p] - centre_scaled[p]|^2, amplitude[p])``.
    """
    n, d = x.shape
    p = inv_scale.size
    out = np.empty((n, p))
    for k in range(n):
        for c in range(p):
            inv = inv_scale[c]
            r2 = 0.0
            for i in range(d):
                u = x[k, i] * inv - centre_scaled[c, i]
                r2 += u * u
            out[k, c] = mexican_hat_r2(r2, amplitude[c])
    return out


@njit_cached(fastmath={"contract"})
def pool_wavelets(
    qd: np.ndarray,
    input_index: np.ndarray,
    centre_scaled: np.ndarray,
    inv_scale: np.ndarray,
    amplitude: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """Wavelets of any joints at every sample: ``qd`` (N, n) -> (N, P).

    ``input_index`` (P, dmax): the velocity each input column reads, ``n`` or more (padding)
    for unused columns.
    """
    n_samples, n = qd.shape
    p, dmax = input_index.shape
    out = np.empty((n_samples, p))
    for k in range(n_samples):
        for c in range(p):
            inv = inv_scale[c]
            r2 = 0.0
            for i in range(dmax):
                index = input_index[c, i]
                if index < n:
                    u = qd[k, index] * inv - centre_scaled[c, i]
                    r2 += u * u
            out[k, c] = mexican_hat_r2(r2, amplitude[c])
    return out


@njit_cached(fastmath={"contract"})
def _wavelet_values_into(
    x0: float, x1: float, table: np.ndarray, d: int, start: int, end: int, psi: np.ndarray
) -> None:  # pragma: no cover - compiled
    """``psi[c]`` = the Mexican hat of wavelet column ``c`` in ``[start, end)`` at ``(x0, x1)``.

    The columns read one velocity (``d == 1``) or two; an unused input has ``x = 0`` and a
    zero centre, so it adds exactly 0 to ``r2``.
    """
    inv = table[d]
    centre0 = table[0]
    if d == 1:
        for c in range(start, end):
            u = x0 * inv[c] - centre0[c]
            psi[c] = mexican_hat_r2(u * u, 1.0)
    else:
        centre1 = table[1]
        for c in range(start, end):
            u = x0 * inv[c] - centre0[c]
            v = x1 * inv[c] - centre1[c]
            psi[c] = mexican_hat_r2(u * u + v * v, 1.0)


@njit_cached(fastmath={"contract", "reassoc"})
def _weighted_sum(psi: np.ndarray, weights: np.ndarray) -> float:  # pragma: no cover - compiled
    """``psi @ weights``, reassociated so that it vectorises (as a BLAS dot would)."""
    total = 0.0
    for c in range(psi.size):
        total += psi[c] * weights[c]
    return total


@njit_cached(fastmath={"contract"})
def wavelet_network_torque_into(
    qd: np.ndarray,
    inputs: np.ndarray,
    table: np.ndarray,
    runs: np.ndarray,
    psi: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Add the torque of a wavelet table at one sample ``qd`` (n,) to ``out`` (n,).

    ``inputs`` (P, d): the velocity each wavelet's input column reads (``n`` or
    more: unused, as in the pool's ``input_index``, with a zero centre); ``table``
    (d + 1 + n, P), one column per wavelet: ``centre_scaled`` (d), ``inv_scale``, then its
    weight ``amplitude * coefficient`` on every joint (a wavelet that several joints'
    networks share is one column); ``runs`` (R, 2): ``[start, end)`` of the columns that read
    the same velocities (sorted so by the table's builder), so that the loops over wavelets
    have no gather and vectorise (one or two inputs; more are evaluated column by column);
    ``psi`` (P) scratch.
    """
    d = inputs.shape[1]
    n = out.size
    if d > 2:  # general input count: one column at a time
        for c in range(inputs.shape[0]):
            r2 = 0.0
            for i in range(d):
                if inputs[c, i] < qd.size:
                    u = qd[inputs[c, i]] * table[d, c] - table[i, c]
                    r2 += u * u
            psi[c] = mexican_hat_r2(r2, 1.0)
    for r in range(runs.shape[0] if d <= 2 else 0):
        start = runs[r, 0]
        x0 = qd[inputs[start, 0]] if inputs[start, 0] < qd.size else 0.0
        x1 = 0.0
        if d > 1 and inputs[start, 1] < qd.size:
            x1 = qd[inputs[start, 1]]
        _wavelet_values_into(x0, x1, table, d, start, runs[r, 1], psi)
    for j in range(n):
        out[j] += _weighted_sum(psi[: inputs.shape[0]], table[d + 1 + j])


# -- coverage trust ----------------------------------------------------------------------------


@njit_cached()
def grid_density(
    qd: np.ndarray,
    inputs: np.ndarray,
    lo: np.ndarray,
    cell: np.ndarray,
    shape: np.ndarray,
    values: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """Density of a grid (``values`` flat, C order) at one sample, multilinear, >= 0.

    Cell centres are at ``lo + (i + 0.5) cell``; between them the value is interpolated,
    outside the grid the missing corners count 0 (and a non-finite velocity gives 0).
    """
    d = inputs.size
    for axis in range(d):
        c = (qd[inputs[axis]] - lo[axis]) / cell[axis] - 0.5
        if not (c > -1.0 and c < shape[axis]):  # also NaN
            return 0.0
    total = 0.0
    for corner in range(1 << d):
        index = 0
        weight = 1.0
        inside = True
        for axis in range(d):
            c = (qd[inputs[axis]] - lo[axis]) / cell[axis] - 0.5
            base = math.floor(c)
            frac = c - base
            upper = (corner >> axis) & 1
            k = int(base) + upper
            if k < 0 or k >= shape[axis]:
                inside = False
                break
            index = index * shape[axis] + k
            weight *= frac if upper else 1.0 - frac
        if inside:
            total += weight * values[index]
    return total if total > 0.0 else 0.0


@njit_cached()
def smoothstep(s: float) -> float:  # pragma: no cover - compiled
    """``3 s^2 - 2 s^3`` of ``s`` clipped to [0, 1]."""
    s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
    return s * s * (3.0 - 2.0 * s)


@njit_cached()
def coverage_trust(density: float, untrained: float, trained: float) -> float:  # pragma: no cover
    """Trust in [0, 1] at a smoothed density: 0 at ``untrained`` or less, 1 at ``trained``."""
    return smoothstep((density - untrained) / (trained - untrained))


@njit_cached()
def trust_blend(w: float, trained: float, fallback: float) -> float:  # pragma: no cover
    """Coverage-aware torque ``w trained + (1 - w) fallback`` at trust ``w`` in [0, 1]."""
    return w * trained + (1.0 - w) * fallback


@njit_cached()
def trust_add(w: float, trained: float, fallback: float) -> float:  # pragma: no cover
    """Torque ``fallback + w trained`` of a network trained on what the fallback leaves."""
    return fallback + w * trained


@njit_cached()
def trust_blend_values(
    w: np.ndarray, trained: np.ndarray, fallback: np.ndarray, on_fallback: bool = False
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`trust_blend` (or, ``on_fallback``, :func:`trust_add`) of three (N, n) arrays."""
    out = np.empty(w.shape)
    for k in range(w.shape[0]):
        for j in range(w.shape[1]):
            if on_fallback:
                out[k, j] = trust_add(w[k, j], trained[k, j], fallback[k, j])
            else:
                out[k, j] = trust_blend(w[k, j], trained[k, j], fallback[k, j])
    return out


@njit_cached()
def grid_density_batch(
    qd: np.ndarray,
    inputs: np.ndarray,
    lo: np.ndarray,
    cell: np.ndarray,
    shape: np.ndarray,
    values: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`grid_density` at every sample: ``qd`` (N, n) -> (N,)."""
    out = np.empty(qd.shape[0])
    for k in range(qd.shape[0]):
        out[k] = grid_density(qd[k], inputs, lo, cell, shape, values)
    return out


@njit_cached()
def coverage_trust_values(
    density: np.ndarray, untrained: float, trained: float
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`coverage_trust` of every entry of a 1-D array of smoothed densities."""
    out = np.empty(density.size)
    for k in range(density.size):
        out[k] = coverage_trust(density[k], untrained, trained)
    return out


@njit_cached()
def coverage_trust_into(
    qd: np.ndarray,
    grid_ints: np.ndarray,
    grid_floats: np.ndarray,
    values: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Trust of every joint's grid at one sample ``qd`` into ``out`` (J,), from a grid table.

    Row ``j`` of ``grid_ints`` is ``[d, offset, inputs (dmax), shape (dmax)]``, of
    ``grid_floats`` ``[untrained, trained, lo (dmax), cell (dmax)]``; grid ``j``'s density
    values are ``values[offset:offset + prod(shape)]`` (C order).
    """
    dmax = (grid_ints.shape[1] - 2) // 2
    for j in range(grid_ints.shape[0]):
        d = grid_ints[j, 0]
        start = grid_ints[j, 1]
        density = grid_density(
            qd,
            grid_ints[j, 2 : 2 + d],
            grid_floats[j, 2 : 2 + d],
            grid_floats[j, 2 + dmax : 2 + dmax + d],
            grid_ints[j, 2 + dmax : 2 + dmax + d],
            values[start:],
        )
        out[j] = coverage_trust(density, grid_floats[j, 0], grid_floats[j, 1])


def term_table_torque(
    qd: np.ndarray, rows: np.ndarray, reach: np.ndarray, parameters: np.ndarray, kind: str
) -> np.ndarray:
    """Torque of a term table at ``qd``: (n,) -> (n,), (N, n) -> (N, n) (ModelError on a bad shape).

    The batch ``torque`` of the Coulomb-viscous models: :func:`linear_friction_torque`.
    """
    from teleop_force.errors import ModelError

    qd = np.asarray(qd, dtype=float)
    single = qd.ndim == 1
    batch = qd.reshape(1, -1) if single else qd
    n = rows.shape[1]
    if batch.ndim != 2 or batch.shape[1] != n:
        raise ModelError(f"{kind}: expected {n} velocities, got {batch.shape[-1]}")
    out = linear_friction_torque(
        np.ascontiguousarray(batch), rows, reach, np.ascontiguousarray(parameters, dtype=float)
    )
    return out[0] if single else out
