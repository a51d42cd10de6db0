"""Compiled (numba) kernels of the wavelet-network fits (batch and Lyapunov adaptation).

:class:`FilteredWavelets` is the inner loop of
:func:`teleop_force.friction.batch_fit.filtered_basis_normal_equations`: it evaluates the
Mexican-hat wavelets ``psi_k(x) = amp_k (1 - r2) exp(-r2 / 2)``, ``r2 = |x a0^-m_k - n_k b0|^2``,
of one joint network on *every* sample, runs the first-order low-pass filter
``y_k[t] = a_t y_k[t-1] + (1 - a_t) psi_k(x[t])`` on every sample, and returns the filtered
rows asked for (every ``row_stride``-th), in one pass over the samples, without the ``(N, P)``
temporaries of the NumPy version. It equals :func:`~teleop_force.friction.wavelet_network.psi_block`
followed by :func:`~teleop_force.lowpass.lowpass_batch` up to the approximations
below (the
tests compare them on random networks: within 1e-13 of the largest value).

How the work is cut:

* **Truncation**: a wavelet is taken as 0 where ``r2 > R2_CUT`` (80: there
  ``|psi| <= 79 e^-40 amp = 3.4e-16 amp``). On the Omni's benchmark data ~75 % of joint 1's
  (sample, wavelet) pairs are that far, ~24 % of joints 2/3's.
* **Only the wavelets within reach along the first input are touched per sample.** The
  columns are sorted by dilation, then by centre; for each dilation (a *line*) the range of
  columns with ``|x_0 a0^-m - n_0 b0| < sqrt(R2_CUT)`` is contiguous and moves little from one
  sample to the next, so it is tracked by moving its two ends (no bisection: its branch
  mispredictions cost more than they saved). For one input that range is exactly the near
  wavelets; for more inputs the others are evaluated (and cut) inside the range.
* **The filter of the far columns costs nothing**: the state is kept as ``y = A z`` with
  ``A`` the product of the filter poles since the last stored row, so a sample changes only
  its near columns (``z += (1 - a_t) / A psi``); at every stored row ``y = A z`` is formed for
  all columns, written out, and the scale reset (``z = y``, ``A = 1``). (``A`` is also reset
  if it falls below 1e-100, e.g. at ``a_t = 0``, the start of the filter.) This is the same
  recursion up to rounding (a few ulp).
* ``exp`` is computed inline so that the loops vectorise (LLVM has no vector ``exp`` without
  Intel's SVML): ``exp(h) = 2^n exp(r)``, ``n = round(h / ln 2)``, ``|r| <= ln(2) / 2`` with a
  two-part ``ln 2``, ``exp(r)`` by its Taylor polynomial of degree 13 (truncation < 2.2e-16
  relative), ``2^n`` built from its exponent bits.
* Filtered values below ``FLUSH`` (1e-150) in magnitude are stored as 0, so no subnormal
  number (~100 times slower to multiply) reaches the filter or the Gram products.

:func:`adapt_samples` is the recursion of
:meth:`teleop_force.friction.adaptation.LyapunovAdapter.run` (see that module), sample by
sample with the same inline ``exp`` (no truncation there).

The compiled code is cached on disk (``cache=True``) next to this file, or where numba's cache
locator finds a writable place; when there is none it is compiled in memory on first use (a
few seconds), with the same code.
"""

from __future__ import annotations

import math
import time

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.friction.terms import mexican_hat_r2

#: Wavelets are 0 beyond this squared normalised distance (``|psi| < 3.4e-16`` of its peak).
R2_CUT = 80.0
#: Filtered values smaller than this in magnitude are stored as 0 (no subnormal numbers).
FLUSH = 1e-150
#: The filter's scale ``A`` is folded into the state when it falls below this.
_A_MIN = 1e-100


@njit_cached(fastmath={"contract"})
def _psi(r2: float, amp: float, cut: float) -> float:  # pragma: no cover - compiled
    """Return the Mexican hat (``terms.mexican_hat_r2``) for ``r2 < cut``, else 0."""
    psi = mexican_hat_r2(r2, amp)
    return psi if r2 < cut else 0.0


@njit_cached(fastmath={"contract"})
def _filtered_rows(
    x: np.ndarray,
    line_inv: np.ndarray,
    line_start: np.ndarray,
    line_lo: np.ndarray,
    line_hi: np.ndarray,
    col_centre: np.ndarray,
    col_amp: np.ndarray,
    a: np.ndarray,
    keep: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    n, d = x.shape
    n_lines = line_inv.size
    p = col_amp.size
    reach = math.sqrt(R2_CUT)
    scale = 1.0
    row = 0
    next_keep = keep[0] if keep.size else -1
    for t in range(n):
        at = a[t]
        scale *= at
        if scale < _A_MIN:
            for k in range(p):
                y = z[k] * scale
                z[k] = y if abs(y) > FLUSH else 0.0
            scale = 1.0
        gain = (1.0 - at) / scale
        x0 = x[t, 0]
        x1 = x[t, 1] if d > 1 else 0.0
        for ln in range(n_lines):
            inv = line_inv[ln]
            u0 = x0 * inv
            left = u0 - reach
            right = u0 + reach
            start = line_start[ln]
            stop = line_start[ln + 1]
            # columns [lo, hi) of the line have |u0 - centre_0| < reach (centre_0 sorted);
            # the range moves little from one sample to the next
            lo = line_lo[ln]
            hi = line_hi[ln]
            while lo > start and col_centre[0, lo - 1] > left:
                lo -= 1
            while lo < stop and col_centre[0, lo] <= left:
                lo += 1
            if hi < lo:
                hi = lo
            while hi < stop and col_centre[0, hi] < right:
                hi += 1
            while hi > lo and col_centre[0, hi - 1] >= right:
                hi -= 1
            line_lo[ln] = lo
            line_hi[ln] = hi
            if d == 1:
                for kk in range(lo, hi):
                    ku = np.uint64(kk)  # unsigned: no wrap-around check, the loop vectorises
                    v = u0 - col_centre[0, ku]
                    z[ku] += gain * _psi(v * v, col_amp[ku], R2_CUT)
            elif d == 2:
                u1 = x1 * inv
                for kk in range(lo, hi):
                    ku = np.uint64(kk)  # unsigned: no wrap-around check, the loop vectorises
                    v = u0 - col_centre[0, ku]
                    w = u1 - col_centre[1, ku]
                    z[ku] += gain * _psi(v * v + w * w, col_amp[ku], R2_CUT)
            else:
                for kk in range(lo, hi):
                    ku = np.uint64(kk)  # unsigned: no wrap-around check, the loop vectorises
                    v = u0 - col_centre[0, ku]
                    r2 = v * v
                    for i in range(1, d):
                        v = x[t, i] * inv - col_centre[i, ku]
                        r2 += v * v
                    z[ku] += gain * _psi(r2, col_amp[ku], R2_CUT)
        if t == next_keep:
            for k in range(p):
                y = z[k] * scale
                y = y if abs(y) > FLUSH else 0.0
                z[k] = y
                out[row, k] = y
            scale = 1.0
            row += 1
            next_keep = keep[row] if row < keep.size else -1
    if scale != 1.0:
        for k in range(p):
            y = z[k] * scale
            z[k] = y if abs(y) > FLUSH else 0.0
    return row


class FilteredWavelets:
    """Low-pass filtered wavelets of one joint network, evaluated chunk by chunk (compiled).

    ``centre_scaled`` (P, d), ``inv_scale`` and ``amplitude`` (P,) describe the wavelets as
    for :func:`~teleop_force.friction.wavelet_network.psi_block`. The filter state (starting
    at 0) carries over from one :meth:`rows` call to the next; see the module docstring.
    :meth:`rows` returns the columns sorted (:attr:`order`): the caller's column ``order[i]``
    is column ``i``.
    """

    def __init__(
        self, centre_scaled: np.ndarray, inv_scale: np.ndarray, amplitude: np.ndarray
    ) -> None:
        """Sort the wavelets into lines: one per dilation, by their first centre coordinate."""
        inv_scale = np.asarray(inv_scale, dtype=np.float64).reshape(-1)
        p = inv_scale.size
        centre_scaled = np.asarray(centre_scaled, dtype=np.float64).reshape(p, -1)
        d = centre_scaled.shape[1]
        if d < 1:
            raise ValueError("wavelets need at least one input")
        keys = [centre_scaled[:, i] for i in range(d - 1, -1, -1)] + [inv_scale]
        order = np.lexsort(keys) if p else np.zeros(0, dtype=np.int64)
        inv_sorted = inv_scale[order]
        new_line = np.ones(p, dtype=bool)
        new_line[1:] = inv_sorted[1:] != inv_sorted[:-1]
        starts = np.flatnonzero(new_line)
        self.size = p
        self.inputs = d
        self._line_inv = np.ascontiguousarray(inv_sorted[starts])
        self._line_start = np.append(starts, p).astype(np.int64)
        self._line_lo = self._line_start[:-1].copy()
        self._line_hi = self._line_start[:-1].copy()
        self._col_centre = np.ascontiguousarray(centre_scaled[order].T)
        self._col_amp = np.ascontiguousarray(np.asarray(amplitude, dtype=np.float64)[order])
        #: Column ``i`` of :meth:`rows` is the caller's wavelet ``order[i]``.
        self.order = order.astype(np.int64)
        self._z = np.zeros(p)

    @property
    def state(self) -> np.ndarray:
        """Filtered values after the last sample, in the caller's column order (a copy)."""
        out = np.empty(self.size)
        out[self.order] = self._z
        return out

    def rows(
        self, x: np.ndarray, a: np.ndarray, keep: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """Filter over samples ``x`` (N, d) with poles ``a`` (N,); return the rows ``keep``.

        ``a[t]`` is the pole of sample ``t`` (``exp(-2 pi f_c dt_t)``; ``a = 0`` restarts the
        filter at that sample's value). ``keep`` are increasing sample indices (R,); returns
        (R, P), in ``out[:R]`` when given (C-contiguous, P columns). The columns are in the
        order of :attr:`order` (sorted by dilation and centre), not the caller's.
        """
        x = np.ascontiguousarray(x, dtype=np.float64)
        a = np.ascontiguousarray(a, dtype=np.float64)
        keep = np.ascontiguousarray(keep, dtype=np.int64)
        if x.ndim != 2 or x.shape[1] != self.inputs or a.shape != (x.shape[0],):
            raise ValueError(f"x must be (N, {self.inputs}) and a (N,)")
        if keep.ndim != 1 or (
            keep.size and (keep[0] < 0 or keep[-1] >= x.shape[0] or np.any(np.diff(keep) <= 0))
        ):
            raise ValueError("keep must be increasing sample indices")
        n_rows = keep.size
        if out is None:
            out = np.empty((n_rows, self.size))
        elif out.shape[0] < n_rows or out.shape[1] != self.size or not out.flags.c_contiguous:
            raise ValueError(f"out must be C-contiguous with >= {n_rows} rows, {self.size} columns")
        if x.shape[0] == 0:
            return out[:0]
        _filtered_rows(
            x, self._line_inv, self._line_start, self._line_lo, self._line_hi,
            self._col_centre, self._col_amp, a, keep, self._z, out,
        )  # fmt: skip
        return out[:n_rows]


@njit_cached(fastmath={"contract"})
def _sum4(values: np.ndarray, lo: int, hi: int) -> float:  # pragma: no cover - compiled
    """``sum(values[lo:hi])`` with four partial sums (a shorter dependency chain)."""
    a0 = a1 = a2 = a3 = 0.0
    k = lo
    while k + 4 <= hi:
        a0 += values[k]
        a1 += values[k + 1]
        a2 += values[k + 2]
        a3 += values[k + 3]
        k += 4
    while k < hi:
        a0 += values[k]
        k += 1
    return (a0 + a1) + (a2 + a3)


@njit_cached(fastmath={"contract"})
def adapt_samples(
    qd: np.ndarray,
    p_l: np.ndarray,
    u_l: np.ndarray,
    dt: np.ndarray,
    start: int,
    errors: np.ndarray,
    inv_scale: np.ndarray,
    centre_scaled_t: np.ndarray,
    joint_inputs: np.ndarray,
    amplitude: np.ndarray,
    joint_start: np.ndarray,
    protected: np.ndarray,
    c: np.ndarray,
    psi_l: np.ndarray,
    gain: np.ndarray,
    decaying: np.ndarray,
    removal_left: np.ndarray,
    prev_abs: np.ndarray,
    a_diag: np.ndarray,
    bound: np.ndarray,
    mu: np.ndarray,
    theta: np.ndarray,
    omega: float,
    decay_tau_s: float,
    removal_time_s: float,
    interval: int,
    update_structure: bool,
    counters: np.ndarray,
    p_hat: np.ndarray,
    done: np.ndarray,
    trigger: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Run the Lyapunov recursion of :class:`~teleop_force.friction.adaptation.LyapunovAdapter`.

    Runs samples ``start, start + 1, ...`` (writing ``errors``) with a fixed active set (its
    wavelets ordered by joint: ``joint_start``; joint ``j`` reads the velocities
    ``joint_inputs[j]``, -1 padded), the structure checks included, until the end or until a
    check that changes the active set (``done`` / ``trigger`` set, ``counters[3] = 1``):
    returns the number of samples processed so far. ``counters`` holds ``[samples since the
    last check, seconds since the last check, p_hat set, change pending]``.
    """
    n_samples, n = qd.shape
    p = c.size
    work = np.empty(p)
    s = np.zeros(n)
    e = np.zeros(n)
    since = int(counters[0])
    elapsed = counters[1]
    any_decay = False
    for k in range(p):
        any_decay = any_decay or decaying[k]
    for t in range(start, n_samples):
        dtt = dt[t]
        at = math.exp(-omega * dtt)
        if counters[2] == 0.0:  # first sample: the filters start at their input
            for i in range(n):
                p_hat[i] = p_l[t, i]
            at = 0.0
            counters[2] = 1.0
        bt = 1.0 - at
        # wavelets, their low-pass filter, and the network outputs s_j = psi_L . c
        for j in range(n):
            lo = joint_start[j]
            hi = joint_start[j + 1]
            x0 = qd[t, joint_inputs[j, 0]]
            if joint_inputs[j, 1] < 0:
                for kk in range(lo, hi):
                    ku = np.uint64(kk)  # unsigned: no wrap-around check, the loop vectorises
                    u = x0 * inv_scale[ku] - centre_scaled_t[0, ku]
                    v = at * psi_l[ku] + bt * _psi(u * u, amplitude[ku], 1e300)
                    psi_l[ku] = v
                    work[ku] = v * c[ku]
            elif joint_inputs.shape[1] == 2 or joint_inputs[j, 2] < 0:
                x1 = qd[t, joint_inputs[j, 1]]
                for kk in range(lo, hi):
                    ku = np.uint64(kk)
                    u = x0 * inv_scale[ku] - centre_scaled_t[0, ku]
                    w = x1 * inv_scale[ku] - centre_scaled_t[1, ku]
                    v = at * psi_l[ku] + bt * _psi(u * u + w * w, amplitude[ku], 1e300)
                    psi_l[ku] = v
                    work[ku] = v * c[ku]
            else:
                for k in range(lo, hi):
                    r2 = 0.0
                    for i in range(joint_inputs.shape[1]):
                        if joint_inputs[j, i] >= 0:
                            u = qd[t, joint_inputs[j, i]] * inv_scale[k] - centre_scaled_t[i, k]
                            r2 += u * u
                    v = at * psi_l[k] + bt * _psi(r2, amplitude[k], 1e300)
                    psi_l[k] = v
                    work[k] = v * c[k]
            s[j] = _sum4(work, lo, hi)
        for j in range(n):
            e[j] = p_l[t, j] - p_hat[j]
            errors[t, j] = e[j]
            p_hat[j] = (1.0 + dtt * a_diag[j]) * p_hat[j] + dtt * (
                u_l[t, j] - s[j] - a_diag[j] * p_l[t, j]
            )
        # the adaptation law, frozen wavelets decaying, the projection on the ball
        decay = math.exp(-dtt / decay_tau_s) if any_decay else 1.0
        for j in range(n):
            step = dtt * e[j]
            lo = joint_start[j]
            hi = joint_start[j + 1]
            for kk in range(lo, hi):
                ku = np.uint64(kk)
                ck = c[ku] - gain[ku] * psi_l[ku] * step
                ck = c[ku] * decay if decaying[ku] else ck
                c[ku] = ck
                work[ku] = ck * ck
            norm2 = _sum4(work, lo, hi)
            if norm2 > bound[j] * bound[j]:
                scale = bound[j] / math.sqrt(norm2)
                for kk in range(lo, hi):
                    c[np.uint64(kk)] *= scale
        since += 1
        elapsed += dtt
        if since < interval:
            continue
        # structure check (Section III-D), as LyapunovAdapter._update_structure
        block_time = elapsed
        since = 0
        elapsed = 0.0
        if not update_structure:
            continue
        change = False
        newly_any = False
        for j in range(n):
            for k in range(joint_start[j], joint_start[j + 1]):
                absc = abs(c[k])
                done[k] = False
                if any_decay and decaying[k]:
                    removal_left[k] -= block_time
                    done[k] = removal_left[k] <= 1e-9 * removal_time_s
                newly = (
                    not decaying[k] and not protected[k] and absc < theta[j] and absc < prev_abs[k]
                )
                trigger[k] = not decaying[k] and absc > mu[j] and prev_abs[k] <= mu[j]
                prev_abs[k] = absc
                if newly:
                    removal_left[k] = removal_time_s
                    decaying[k] = True
                    gain[k] = 0.0
                    newly_any = True
                change = change or done[k] or trigger[k]
        any_decay = any_decay or newly_any
        if change:
            counters[0] = since
            counters[1] = elapsed
            counters[3] = 1.0
            return t + 1
    counters[0] = since
    counters[1] = elapsed
    return n_samples


def warm_up() -> float:
    """Compile (or load from the disk cache) the kernel on a tiny problem; return seconds.

    The first call of a numba function in a process compiles it, or loads the compiled code
    from the cache: :func:`~teleop_force.friction.batch_fit.fit_batch` pays that once.
    Benchmarks call this first so that their figures are the steady state.
    """
    start = time.perf_counter()
    wavelets = FilteredWavelets(np.zeros((2, 1)), np.ones(2), np.ones(2))
    wavelets.rows(np.zeros((3, 1)), np.full(3, 0.5), np.arange(3))
    return time.perf_counter() - start
