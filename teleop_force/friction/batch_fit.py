r"""Batch least-squares fit of a :class:`WaveletNetwork`'s linear parameters (paper Section III).

The batch alternative to the on-line Lyapunov law of :mod:`teleop_force.friction.adaptation`:
:func:`fit_batch` solves ridge-regularised least squares of the same low-pass filtered basis
``Psi_L`` against a filtered friction-torque target. Its steps:

1. group the joints by pool geometry (the Omni's joints 2 and 3 share one);
2. choose each group's candidate wavelets (the active set, or the visited pool wavelets, the
   best by :func:`wavelet_scores` when they are too many);
3. build the normal equations of the filtered basis in chunks from every ``row_stride``-th
   filtered row (the basis is evaluated and filtered on every sample by the compiled
   :class:`teleop_force.friction.kernels.FilteredWavelets`); joints with the same candidates
   share one Gram matrix;
4. solve, pruning negligible wavelets and refitting;
5. write the active sets and coefficients back into the network and summarise.

Steps 2 to 4 run in one thread per group of joints, BLAS on one thread (threadpoolctl).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.fft import irfftn, next_fast_len, rfftn
from scipy.linalg import cho_factor, cho_solve
from scipy.ndimage import uniform_filter
from threadpoolctl import threadpool_limits

from teleop_force.errors import ConfigurationError, DataError, ModelError
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.wavelet_network import (
    WaveletJointSpec,
    WaveletNetwork,
    mexican_hat,
    wavelet_amplitude,
)
from teleop_force.lowpass import DEFAULT_CUTOFF_HZ, lowpass_batch, regularised_intervals


@dataclass(frozen=True)
class BatchFitResult:
    """Summary of :func:`fit_batch`.

    Attributes:
        samples: Samples used (before ``row_stride``).
        candidates: Wavelets per joint that entered the least squares.
        sizes: Active wavelets per joint after pruning.
        rms_nm: RMS of the filtered-torque residual per joint [N m].
        relative_rms: ``rms_nm / RMS(target_L)`` per joint.
        wall_time_s: Processing time.

    """

    samples: int
    candidates: tuple[int, ...]
    sizes: tuple[int, ...]
    rms_nm: np.ndarray
    relative_rms: np.ndarray
    wall_time_s: float

    def __post_init__(self) -> None:
        if len(self.candidates) != len(self.sizes):
            raise ConfigurationError("BatchFitResult: per-joint fields differ in length")


def filtered_basis_normal_equations(
    network: WaveletNetwork,
    joint: int,
    indices: np.ndarray,
    t_s: np.ndarray,
    qd: np.ndarray,
    targets: np.ndarray,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    row_stride: int = 1,
    chunk_samples: int = 16384,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(G, b, yy, rows)`` of the low-pass filtered wavelets ``indices`` against ``targets``.

    ``G = Psi_L^T Psi_L``, ``b = Psi_L^T Y``, ``yy = sum Y^2`` per column of ``targets`` (N, r),
    over every ``row_stride``-th sample (samples 0, ``row_stride``, ...). ``Psi_L`` equals
    ``lowpass_batch(basis, t_s)``: the wavelets are evaluated and filtered on *every* sample
    by the compiled :class:`~teleop_force.friction.kernels.FilteredWavelets` (to ~1e-15
    relative, see there), ``chunk_samples`` samples at a time with the filter state carried
    over; only the kept rows enter the products.
    """
    from teleop_force.friction.kernels import FilteredWavelets  # numba: imported when used

    dt = regularised_intervals(t_s)
    a = np.exp(-2.0 * math.pi * cutoff_hz * dt)
    a[0] = 0.0  # the filter starts at the first value, as lowpass_batch
    indices = np.asarray(indices, dtype=np.int64)
    pool = network.pool
    spec = network.specs[joint]
    x = np.ascontiguousarray(np.asarray(qd, dtype=float)[:, list(spec.inputs)])
    wavelets = FilteredWavelets(
        pool.centre_scaled[indices, : spec.d], pool.inv_scale[indices], pool.amplitude[indices]
    )
    p = indices.size
    gram = np.zeros((p, p))
    rhs = np.zeros((p, targets.shape[1]))
    yy = np.zeros(targets.shape[1])
    keep_all = np.arange(0, x.shape[0], row_stride, dtype=np.int64)
    buffer = np.empty((min(keep_all.size, -(-chunk_samples // row_stride)), p))
    rows = 0
    for start in range(0, x.shape[0], chunk_samples):
        stop = min(start + chunk_samples, x.shape[0])
        keep = keep_all[np.searchsorted(keep_all, start) : np.searchsorted(keep_all, stop)]
        sel = wavelets.rows(x[start:stop], a[start:stop], keep - start, buffer)
        tgt = targets[keep]
        gram += sel.T @ sel
        rhs += sel.T @ tgt
        yy += np.sum(tgt * tgt, axis=0)
        rows += sel.shape[0]
    # the kernel's columns are sorted (wavelets.order): back to the order of ``indices``
    back = np.argsort(wavelets.order)
    return gram[np.ix_(back, back)], rhs[back], yy, rows


def wavelet_visits(network: WaveletNetwork, joint: int, qd: np.ndarray) -> np.ndarray:
    """Count, per pool wavelet of ``joint``, the samples near its centre -> (K_j,).

    A sample counts for a wavelet when its nearest centre on that wavelet's dilation grid is
    the wavelet itself or one of its same-dilation neighbours (within 1.5 grid steps per axis).
    """
    pool = network.pool
    spec = network.specs[joint]
    x = np.asarray(qd, dtype=float)[:, list(spec.inputs)]
    sl = pool.joint_slice(joint)
    visits = np.zeros(pool.joint_size(joint))
    for m in range(spec.m_max, spec.m_min - 1, -1):
        members = np.flatnonzero(pool.m[sl] == m)
        n_lo = pool.n[sl][members].min(axis=0)[: spec.d]
        shape = tuple(int(v) for v in pool.n[sl][members].max(axis=0)[: spec.d] - n_lo + 1)
        cell = np.rint(x / (pool.a0**m * pool.b0)).astype(np.int64) - n_lo
        inside = np.all((cell >= 0) & (cell < np.asarray(shape)), axis=1)
        counts = (
            np.bincount(
                np.ravel_multi_index(tuple(cell[inside].T), shape), minlength=int(np.prod(shape))
            )
            .reshape(shape)
            .astype(float)
        )
        boxed = uniform_filter(counts, size=3, mode="constant") * 3**spec.d
        visits[members] = boxed.reshape(-1)
    return np.rint(visits)


def wavelet_scores(
    network: WaveletNetwork, joint: int, qd: np.ndarray, target: np.ndarray
) -> np.ndarray:
    """How much each pool wavelet of ``joint`` would explain of ``target`` (K_j,), >= 0.

    The samples are binned on the finest dilation's grid (cell means ``f``, counts ``w``);
    for every wavelet ``k`` the score is ``(sum w psi_k (f - f_loc))^2 / sum w psi_k^2`` with
    ``f_loc`` the Gaussian-weighted local mean under ``k``'s envelope: the discrete wavelet
    transform ``<f, psi_k>`` of the paper, made insensitive to the local level (the Mexican hat
    has zero mean only over a fully visited support), i.e. the squared-error reduction of
    fitting ``k`` alone to the locally de-meaned target. Computed with FFT convolutions.
    """
    y = np.asarray(target, dtype=float).reshape(-1, 1)
    return wavelet_scores_of_targets(network, joint, qd, y)[0]


class _SameConvolution:
    """``scipy.signal.fftconvolve(a, kernel, mode="same")`` for one pair of shapes, reusable.

    The same steps as SciPy's (``rfftn`` at the next fast length of the full size, product,
    ``irfftn``, centred slice), so the values are the same bit for bit; a transform computed
    once serves every convolution that uses that array.
    """

    def __init__(self, shape: tuple[int, ...], kernel_shape: tuple[int, ...]) -> None:
        self.shape = shape
        self.full = [a + b - 1 for a, b in zip(shape, kernel_shape, strict=True)]
        self.fshape = [next_fast_len(n, True) for n in self.full]
        self.axes = list(range(len(shape)))

    def transform(self, a: np.ndarray) -> np.ndarray:
        return rfftn(a, self.fshape, axes=self.axes)

    def convolve(self, spectrum: np.ndarray, kernel_spectrum: np.ndarray) -> np.ndarray:
        full = irfftn(spectrum * kernel_spectrum, self.fshape, axes=self.axes)
        full = full[tuple(slice(n) for n in self.full)]
        start = [(f - s) // 2 for f, s in zip(full.shape, self.shape, strict=True)]
        centred = tuple(slice(a, a + s) for a, s in zip(start, self.shape, strict=True))
        return full[centred].copy()


def wavelet_scores_of_targets(
    network: WaveletNetwork, joint: int, qd: np.ndarray, targets: np.ndarray
) -> np.ndarray:
    """:func:`wavelet_scores` of every column of ``targets`` (N, r) -> (r, K_j).

    The sample counts and their convolutions are computed once for all targets (the Omni's
    joints 2 and 3 read the same velocities); the values equal ``wavelet_scores`` per column.
    """
    targets = np.asarray(targets, dtype=float).reshape(np.shape(qd)[0], -1)
    finite = np.isfinite(targets)
    if not np.all(finite) and targets.shape[1] > 1:
        # the counts depend on which samples are finite: one target at a time
        return np.concatenate(
            [wavelet_scores_of_targets(network, joint, qd, targets[:, [c]]) for c in
             range(targets.shape[1])]
        )  # fmt: skip
    pool = network.pool
    spec = network.specs[joint]
    sl = pool.joint_slice(joint)
    x = np.asarray(qd, dtype=float)[:, list(spec.inputs)]
    h = pool.a0**spec.m_min * pool.b0
    pad = math.ceil(pool.a0**spec.m_max * pool.b0 / h) + 1
    lo = np.rint(np.asarray(spec.x_min_rad_s) / h).astype(np.int64) - pad
    hi = np.rint(np.asarray(spec.x_max_rad_s) / h).astype(np.int64) + pad
    shape = tuple(int(v) for v in hi - lo + 1)
    cell = np.rint(x / h).astype(np.int64) - lo
    inside = np.all((cell >= 0) & (cell < np.asarray(shape)), axis=1) & np.all(finite, axis=1)
    flat = np.ravel_multi_index(tuple(cell[inside].T), shape)
    size = int(np.prod(shape))
    w = np.bincount(flat, minlength=size).reshape(shape).astype(float)
    wfs = [
        np.bincount(flat, weights=targets[inside, c], minlength=size).reshape(shape)
        for c in range(targets.shape[1])
    ]
    scores = np.zeros((targets.shape[1], pool.joint_size(joint)))
    for m in range(spec.m_max, spec.m_min - 1, -1):
        scale = pool.a0**m
        radius = math.ceil(4.0 * scale / h)
        offsets = np.indices((2 * radius + 1,) * spec.d).reshape(spec.d, -1).T - radius
        r = offsets * h / scale
        kernel_shape = (2 * radius + 1,) * spec.d
        psi = (wavelet_amplitude(pool.a0, spec.d, m) * mexican_hat(r)).reshape(kernel_shape)
        gauss = np.exp(-0.5 * np.sum(r * r, axis=1)).reshape(kernel_shape)
        conv = _SameConvolution(shape, kernel_shape)
        psi_s, gauss_s, psi2_s = (conv.transform(k) for k in (psi, gauss, psi * psi))
        w_s = conv.transform(w)
        conv_b = conv.convolve(w_s, psi_s)
        conv_gn = conv.convolve(w_s, gauss_s)
        conv_q = conv.convolve(w_s, psi2_s)
        members = np.flatnonzero(pool.m[sl] == m)
        centres = pool.centre[sl][members, : spec.d]
        c_cell = np.rint(centres / h).astype(np.int64) - lo
        ok = np.all((c_cell >= 0) & (c_cell < np.asarray(shape)), axis=1)
        for c, wf in enumerate(wfs):
            wf_s = conv.transform(wf)
            conv_a = conv.convolve(wf_s, psi_s)
            conv_gf = conv.convolve(wf_s, gauss_s)
            local = np.divide(conv_gf, conv_gn, out=np.zeros(shape), where=conv_gn > 1e-9)
            detail = conv_a - conv_b * local
            score = np.divide(detail**2, conv_q, out=np.zeros(shape), where=conv_q > 1e-12)
            vals = np.zeros(members.size)
            vals[ok] = score[tuple(c_cell[ok].T)]
            scores[c, members] = np.maximum(vals, 0.0)
    return scores


def _solve_ridge(gram: np.ndarray, rhs: np.ndarray, ridge: float) -> np.ndarray:
    scale = float(np.mean(np.diag(gram))) if gram.size else 0.0
    reg = gram + (ridge * max(scale, 1e-300)) * np.eye(gram.shape[0])
    try:
        return cho_solve(cho_factor(reg), rhs)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(reg, rhs, rcond=None)[0]


@dataclass(frozen=True)
class _PrunedSolution:
    """Ridge solution after pruning: kept columns of the Gram matrix and their coefficients."""

    keep: np.ndarray
    coefficients: np.ndarray


def _ridge_with_pruning(
    gram: np.ndarray, rhs: np.ndarray, amplitude: np.ndarray, ridge: float, prune_tol_nm: float
) -> _PrunedSolution:
    """Solve, drop wavelets with peak contribution < ``prune_tol_nm``, refit (<= 5 rounds)."""
    keep = np.arange(rhs.size)
    coef = np.zeros(0)
    for _ in range(5):
        if keep.size == 0:
            return _PrunedSolution(keep, np.zeros(0))
        coef = _solve_ridge(gram[np.ix_(keep, keep)], rhs[keep], ridge)
        small = np.abs(coef) * amplitude[keep] < prune_tol_nm
        if not np.any(small):
            return _PrunedSolution(keep, coef)
        keep = keep[~small]
    if keep.size == 0:
        return _PrunedSolution(keep, np.zeros(0))
    return _PrunedSolution(keep, _solve_ridge(gram[np.ix_(keep, keep)], rhs[keep], ridge))


def fit_coupled_cv(
    t_s: np.ndarray,
    qd: np.ndarray,
    target_L: np.ndarray,
    friction_inputs: Sequence[Sequence[int]],
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
) -> CoupledCoulombViscous:
    """Least-squares coupled Coulomb+viscous model of the filtered friction target (N x n)."""
    qd = np.asarray(qd, dtype=float)
    target_L = np.asarray(target_L, dtype=float)
    n = qd.shape[1]
    model = CoupledCoulombViscous(n, tuple(tuple(s) for s in friction_inputs))
    for j in range(n):
        basis_l = lowpass_batch(model.basis(j, qd), t_s, cutoff_hz)
        solution = np.linalg.lstsq(basis_l, target_L[:, j], rcond=None)[0]
        model.set_joint_parameters(j, solution)
    return model


# -- fit_batch and its steps ---------------------------------------------------------------------


@dataclass(frozen=True)
class _FitInputs:
    """The recording to fit, checked: times (N,), velocities and target (N, n)."""

    t_s: np.ndarray
    qd: np.ndarray
    target_l: np.ndarray


@dataclass(frozen=True)
class _FitOptions:
    """The options of :func:`fit_batch` that the per-group steps read (checked)."""

    cutoff_hz: float
    ridge: float
    wavelets: Literal["visited", "active"]
    max_wavelets_per_joint: int
    min_visits: int
    prune_tol_nm: float
    row_stride: int
    chunk_samples: int

    def __post_init__(self) -> None:
        if self.wavelets not in ("visited", "active"):
            raise ConfigurationError(
                f"wavelets must be 'visited' or 'active', got {self.wavelets!r}"
            )
        if (
            not self.ridge >= 0.0
            or self.row_stride < 1
            or self.max_wavelets_per_joint < 1
            or self.chunk_samples < 1
        ):
            raise ConfigurationError("need ridge >= 0, row_stride >= 1, max_wavelets >= 1")


@dataclass(frozen=True)
class _CandidateSet:
    """Joints of one group that share their candidates, hence one Gram matrix.

    ``local`` are indices into each joint's own pool (0..K_j-1).
    """

    joints: tuple[int, ...]
    local: np.ndarray


@dataclass(frozen=True)
class _NormalEquations:
    """:func:`filtered_basis_normal_equations` of one candidate set (a target per joint)."""

    gram: np.ndarray
    rhs: np.ndarray
    yy: np.ndarray
    rows: int


@dataclass(frozen=True)
class _JointFit:
    """One joint's fit: what :func:`fit_batch` writes back into the network and reports."""

    joint: int
    candidates: int
    kept: np.ndarray  # global pool indices
    coefficients: np.ndarray
    rms_nm: float
    relative_rms: float


def _checked_inputs(
    network: WaveletNetwork, t_s: np.ndarray, qd: np.ndarray, target_l: np.ndarray
) -> _FitInputs:
    """Convert to float arrays; DataError on a shape mismatch or a non-finite value."""
    qd = np.asarray(qd, dtype=float)
    target_l = np.asarray(target_l, dtype=float)
    t_arr = np.asarray(t_s, dtype=float).reshape(-1)
    n = network.n_joints
    if qd.shape != (t_arr.size, n) or target_l.shape != (t_arr.size, n):
        raise DataError(
            f"qd and target_L must be ({t_arr.size}, {n}), got {qd.shape}, {target_l.shape}"
        )
    if not (np.all(np.isfinite(qd)) and np.all(np.isfinite(target_l))):
        raise DataError("qd / target_L contain non-finite values")
    return _FitInputs(t_s=t_arr, qd=qd, target_l=target_l)


def _geometry_key(spec: WaveletJointSpec) -> tuple[object, ...]:
    return (spec.inputs, spec.x_min_rad_s, spec.x_max_rad_s, spec.m_min, spec.m_max)


def _geometry_groups(network: WaveletNetwork) -> list[tuple[int, ...]]:
    """Joints grouped by pool geometry, in order of their first joint."""
    groups: dict[tuple[object, ...], list[int]] = {}
    for j in range(network.n_joints):
        groups.setdefault(_geometry_key(network.specs[j]), []).append(j)
    return [tuple(members) for members in groups.values()]


def _visited_candidates(
    network: WaveletNetwork, members: tuple[int, ...], inputs: _FitInputs, options: _FitOptions
) -> np.ndarray:
    """Local indices of the visited wavelets of a group, the best ones when too many."""
    pool = network.pool
    j0 = members[0]
    off = int(pool.joint_offsets[j0])
    visited = np.flatnonzero(wavelet_visits(network, j0, inputs.qd) >= options.min_visits)
    if visited.size <= options.max_wavelets_per_joint:
        return visited
    total = np.zeros(pool.joint_size(j0))
    targets = inputs.target_l[:, list(members)]
    for sc in wavelet_scores_of_targets(network, j0, inputs.qd, targets):
        total += sc / max(float(sc.max()), 1e-300)
    coarse = visited[pool.m[off + visited] == network.specs[j0].m_max]
    rest = np.setdiff1d(visited, coarse)
    budget = max(0, options.max_wavelets_per_joint - coarse.size)
    best = rest[np.argsort(-total[rest], kind="stable")[:budget]]
    return np.sort(np.concatenate((coarse, best)))


def _candidate_sets(
    network: WaveletNetwork, members: tuple[int, ...], inputs: _FitInputs, options: _FitOptions
) -> list[_CandidateSet]:
    """Choose the candidates of a group's joints; joints with equal candidates share a set."""
    if options.wavelets == "visited":
        return [_CandidateSet(members, _visited_candidates(network, members, inputs, options))]
    local = {j: network.active_indices(j) for j in members}
    sets: list[_CandidateSet] = []
    for j in members:
        if any(j in s.joints for s in sets):
            continue
        same = tuple(i for i in members if np.array_equal(local[i], local[j]))
        sets.append(_CandidateSet(same, local[j]))
    return sets


def _normal_equations(
    network: WaveletNetwork, candidates: _CandidateSet, inputs: _FitInputs, options: _FitOptions
) -> _NormalEquations:
    """Build the filtered basis's normal equations of a candidate set, a column per joint."""
    offset = int(network.pool.joint_offsets[candidates.joints[0]])
    gram, rhs, yy, rows = filtered_basis_normal_equations(
        network, candidates.joints[0], candidates.local + offset, inputs.t_s, inputs.qd,
        inputs.target_l[:, list(candidates.joints)], options.cutoff_hz, options.row_stride,
        options.chunk_samples,
    )  # fmt: skip
    return _NormalEquations(gram=gram, rhs=rhs, yy=yy, rows=rows)


def _solve_joint(
    network: WaveletNetwork,
    candidates: _CandidateSet,
    column: int,
    equations: _NormalEquations,
    options: _FitOptions,
) -> _JointFit:
    """Solve for the joint of ``column`` (pruned ridge) and measure its residual."""
    pool = network.pool
    joint = candidates.joints[column]
    amp = pool.amplitude[candidates.local + int(pool.joint_offsets[candidates.joints[0]])]
    gram, rhs, yy, rows = equations.gram, equations.rhs, equations.yy, equations.rows
    solution = _ridge_with_pruning(gram, rhs[:, column], amp, options.ridge, options.prune_tol_nm)
    keep, coef = solution.keep, solution.coefficients
    gk = gram[np.ix_(keep, keep)]
    sse = float(yy[column] - 2.0 * coef @ rhs[keep, column] + coef @ gk @ coef)
    rms = math.sqrt(max(sse, 0.0) / max(rows, 1))
    relative = rms / max(math.sqrt(float(yy[column]) / max(rows, 1)), 1e-300)
    return _JointFit(
        joint=joint,
        candidates=len(candidates.local),
        kept=candidates.local[keep] + int(pool.joint_offsets[joint]),
        coefficients=coef,
        rms_nm=rms,
        relative_rms=relative,
    )


def _fit_group(
    network: WaveletNetwork, members: tuple[int, ...], inputs: _FitInputs, options: _FitOptions
) -> list[_JointFit]:
    """Choose the candidates of a group of joints sharing a pool geometry and fit them."""
    fits: list[_JointFit] = []
    for candidates in _candidate_sets(network, members, inputs, options):
        equations = _normal_equations(network, candidates, inputs, options)
        fits.extend(
            _solve_joint(network, candidates, column, equations, options)
            for column in range(len(candidates.joints))
        )
    return fits


def _fit_groups_in_threads(
    network: WaveletNetwork,
    groups: list[tuple[int, ...]],
    inputs: _FitInputs,
    options: _FitOptions,
    *,
    update_coverage: bool,
) -> list[_JointFit]:
    """Fit the groups, one thread each, BLAS on one thread; the fits in joint order.

    With ``update_coverage`` the samples are counted into the network's coverage map
    meanwhile.
    """
    # the groups are independent: one thread each (the kernel and BLAS release the GIL)
    workers = max(1, min(len(groups), os.cpu_count() or 1))
    # one BLAS thread for the whole pool: threadpoolctl's limit is process-wide and restored
    # on exit, so it is set once here, around every group's thread, not inside each
    with (
        threadpool_limits(limits=1, user_api="blas"),
        ThreadPoolExecutor(max_workers=workers, thread_name_prefix="fit_batch") as executor,
    ):
        futures = [
            executor.submit(_fit_group, network, members, inputs, options) for members in groups
        ]
        if update_coverage and network.coverage is not None:
            network.coverage.add(inputs.qd)
        fits = [fit for future in futures for fit in future.result()]
    return sorted(fits, key=lambda fit: fit.joint)


def _write_back(network: WaveletNetwork, fits: list[_JointFit]) -> None:
    """Replace each joint's active set and coefficients by its fit."""
    for fit in fits:
        network.set_structure(fit.joint, fit.kept, fit.coefficients)


def _check_finite(network: WaveletNetwork) -> None:
    if any(not np.all(np.isfinite(network.joint_parameters(j))) for j in range(network.n_joints)):
        raise ModelError("fit_batch: least squares produced non-finite coefficients")


def _summary(
    network: WaveletNetwork, inputs: _FitInputs, fits: list[_JointFit], wall_time_s: float
) -> BatchFitResult:
    n = network.n_joints
    candidates = [0] * n
    sizes = [0] * n
    rms = np.zeros(n)
    rel = np.zeros(n)
    for fit in fits:
        candidates[fit.joint] = fit.candidates
        sizes[fit.joint] = int(fit.kept.size)
        rms[fit.joint] = fit.rms_nm
        rel[fit.joint] = fit.relative_rms
    return BatchFitResult(
        samples=int(inputs.t_s.size),
        candidates=tuple(candidates),
        sizes=tuple(sizes),
        rms_nm=rms,
        relative_rms=rel,
        wall_time_s=wall_time_s,
    )


def fit_batch(
    network: WaveletNetwork,
    t_s: np.ndarray,
    qd: np.ndarray,
    target_L: np.ndarray,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    ridge: float = 1e-8,
    *,
    wavelets: Literal["visited", "active"] = "visited",
    max_wavelets_per_joint: int = 300,
    min_visits: int = 20,
    prune_tol_nm: float = 1e-5,
    row_stride: int = 1,
    chunk_samples: int = 16384,
    update_coverage: bool = True,
    fit_fallback: bool = True,
) -> BatchFitResult:
    """Batch ridge least squares of the WN's filtered basis against ``target_L`` (N x n).

    ``target_L`` is the filtered friction torque (filtered motor torque minus filtered
    rigid-body torque). ``wavelets="active"`` fits the current active set (e.g. grown by
    :class:`~teleop_force.friction.adaptation.LyapunovAdapter`); ``"visited"`` takes the pool
    wavelets with at least ``min_visits`` samples within one grid step of their centre and,
    when they are more than ``max_wavelets_per_joint``, keeps all visited wavelets of the
    coarsest dilation plus the best by :func:`wavelet_scores` (joints with identical pools, like
    the Omni's 2 and 3, share the candidates via their summed normalised scores, and so one
    Gram matrix). ``ridge`` is relative to the mean diagonal of the Gram matrix. Wavelets whose
    peak contribution ``|c| a0^(-d m/2)`` is below ``prune_tol_nm`` are pruned and the rest
    refitted. The network's active sets and coefficients are replaced; with ``fit_fallback``
    its coupled-CV fallback is fitted to the same target; with ``update_coverage`` the samples
    are counted into its coverage map.

    ``row_stride`` > 1 builds the normal equations from every ``row_stride``-th row of the
    filtered basis (the basis is still evaluated and filtered on every sample); ``rms_nm`` and
    ``relative_rms`` are then over those rows. The identification pipeline uses
    :func:`teleop_force.identification.wavelet_training.batch_row_stride` (3 at 1 kHz and 8 Hz).
    Groups of joints with the same pool geometry are fitted in parallel threads, with BLAS on
    one thread (``threadpoolctl.threadpool_limits``): OpenBLAS's workers busy-wait between the
    small calls, which on shared cores were measured 10 to 400 times slower than one thread.
    """
    start_wall = time.perf_counter()
    inputs = _checked_inputs(network, t_s, qd, target_L)
    options = _FitOptions(
        cutoff_hz=cutoff_hz, ridge=ridge, wavelets=wavelets,
        max_wavelets_per_joint=max_wavelets_per_joint, min_visits=min_visits,
        prune_tol_nm=prune_tol_nm, row_stride=row_stride, chunk_samples=chunk_samples,
    )  # fmt: skip
    groups = _geometry_groups(network)
    fits = _fit_groups_in_threads(network, groups, inputs, options, update_coverage=update_coverage)
    _write_back(network, fits)
    if fit_fallback:
        network.fallback = fit_coupled_cv(
            inputs.t_s, inputs.qd, inputs.target_l, [s.inputs for s in network.specs], cutoff_hz
        )
    _check_finite(network)
    return _summary(network, inputs, fits, time.perf_counter() - start_wall)
