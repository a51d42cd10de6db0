r"""Lyapunov adaptation of a :class:`WaveletNetwork` (paper Section III-C/D).

Identifier (derivation)
-----------------------
The paper's series-parallel model (7) is garbled; we use the same idea in *momentum*
coordinates on *low-pass filtered* signals, which needs neither accelerations nor ``M^-1``.
With ``p = M(q) qd`` the generalized momentum, the dynamics (1) read
``dp/dt = tau - w(q, qd) - tau_f(qd)`` with ``w = N + tau_spring - C^T qd`` (using
``dM/dt = C + C^T``). The low-pass filter ``L = omega / (s + omega)`` commutes with ``d/dt``,
so with ``p_L``, ``u_L = tau_L - w_L`` and the filtered basis ``Psi_L`` (``tau_f = Psi c* + eps``)::

    d/dt p_L = u_L - Psi_L c* - eps                                   (plant, filtered)
    d/dt p_hat = A (p_hat - p_L) + u_L - Psi_L c_hat                  (identifier)
    e = p_L - p_hat  =>  de/dt = A e - Psi_L c_tilde - eps,   c_tilde = c* - c_hat   (cf. 9)

With ``D = diag(inertia_kgm2)`` (default identity) take
``V = 1/2 e^T D^-1 e + 1/2 c_tilde^T Gamma^-1 c_tilde``. Since ``d c_tilde/dt = -d c_hat/dt``::

    dV/dt = e^T D^-1 A e - e^T D^-1 Psi_L c_tilde - e^T D^-1 eps - c_tilde^T Gamma^-1 dc_hat/dt

and the cross term cancels for **d c_hat/dt = -Gamma Psi_L^T D^-1 e**, leaving
``dV/dt = e^T D^-1 A e - e^T D^-1 eps <= -lambda |e|^2 + |e| |D^-1| eps_max`` (A, D diagonal,
A Hurwitz). The sign is *minus*, as in the paper's (8), for ``e = measured - estimated``:
when the true friction exceeds the estimate the measured momentum falls below the prediction
(``e < 0``) and ``c_hat`` must grow. (The ``+Gamma Psi_L^T e`` of the task brief is the law for
``e = p_hat - p_L``.) ``D`` is an optional constant weighting: with ``D`` = the diagonal of
``M`` (~1e-3 kg m^2 on the Omni) ``D^-1 e`` is a velocity error as in the paper, so the paper's
``Gamma`` (0.08, 0.05, 0.05) gives the paper's adaptation speed; with ``D = I`` the same
``Gamma`` adapts ~1000 times slower. Because ``A`` and ``D`` are diagonal, ``V`` splits into
one term per joint network and each network is projected on its own ball.

Projection (8): ``||c_hat_j|| <= B_j`` per network. In discrete time the update is followed by
the Euclidean projection onto the ball (radial scaling when ``||c_hat_j|| > B_j``), the discrete
counterpart of removing the outward component on the boundary; the bound then holds exactly at
every sample.

Discretisation (1 kHz, Euler as in the paper) for sample ``k`` with interval ``dt_k`` (time
since the previous sample; ``a_k = exp(-omega dt_k)``)::

    Psi_L[k]  = a_k Psi_L[k-1] + (1 - a_k) psi(qd[k])        (starts at psi(qd[0]))
    e[k]      = p_L[k] - p_hat[k]                              (p_hat starts at p_L[0])
    c[k+1]    = proj( c[k] - dt_k Gamma D^-1 Psi_L[k]^T e[k] )
    p_hat[k+1] = p_hat[k] + dt_k (A (p_hat[k] - p_L[k]) + u_L[k] - Psi_L[k] c[k])

Speed: :meth:`LyapunovAdapter.run` runs the recursion above sample by sample, with the
projection at every sample, and the structure checks below, in one compiled loop
(:func:`teleop_force.friction.kernels.adapt_samples`, numba); it hands over to Python only at
a check that changes the active set (activating neighbours, removing wavelets), then resumes.
:meth:`LyapunovAdapter.step` (one sample, the service's streaming path) does the same in
NumPy; the two agree up to rounding (tests).

Structure (Section III-D), checked every ``structure_interval`` samples, vectorised:

* inclusion: when an active wavelet's ``|c|`` *becomes* greater than ``mu`` (it was
  ``<= mu`` at the previous check; new wavelets start at 0) its pool neighbours are activated
  (coefficient 0; filtered-basis state set to their *current raw value*, the convention of
  :class:`teleop_force.lowpass.LowPass` for a filter's first sample). Reading
  "becomes" as
  the crossing event, not the level, keeps a removed neighbour of a large wavelet out until
  some wavelet crosses ``mu`` again (with the level reading the pair ``theta > mu`` makes
  removed neighbours come back at once, an endless include/remove churn);
* exclusion: an active wavelet with ``|c| < theta`` whose ``|c|`` decreased since the last
  check is frozen (no more adaptation) and its coefficient decays as ``exp(-t / tau)``,
  ``tau = removal_time_s / 5`` (default 50 ms / 5); after ``removal_time_s`` (< 1 % of the
  value left, itself < theta) it is deactivated. The decay never overshoots zero whatever the
  check interval. The ``2^d`` seed wavelets are kept (``keep_seeds``, a deviation: the paper
  does not say) so a network can never empty itself. Removals and the thresholds are applied
  per network with vector operations; a structure change re-gathers the flat working arrays.

Batch alternative: :func:`teleop_force.friction.batch_fit.fit_batch` solves ridge-regularised
least squares of the same filtered basis against a filtered friction-torque target.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.friction.terms import pool_wavelets
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.lowpass import DEFAULT_CUTOFF_HZ, regularised_intervals

#: An excluded wavelet's coefficient decays as ``exp(-t / tau)`` with
#: ``tau = removal_time_s / REMOVAL_TIME_CONSTANTS``; after ``removal_time_s`` (e^-5, < 1 %
#: left) it is deactivated.
REMOVAL_TIME_CONSTANTS = 5.0


def _per_joint(name: str, value: float | Sequence[float] | np.ndarray, n: int) -> tuple[float, ...]:
    arr = np.atleast_1d(np.asarray(value, dtype=float)).reshape(-1)
    if arr.size == 1:
        arr = np.repeat(arr, n)
    if arr.size != n:
        raise ConfigurationError(f"{name}: need 1 or {n} values, got {arr.size}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class AdaptationConfig:
    """Gains and schedule of :class:`LyapunovAdapter` (one value per joint network).

    Attributes:
        A_diag: Diagonal of the Hurwitz matrix ``A`` [1/s] (all < 0; paper: -300).
        gamma: Adaptation gain of each network (``Gamma = gamma_j I``; paper 0.08, 0.05, 0.05).
        bound_b: Projection radius ``B`` of each network's coefficient vector.
        inertia_kgm2: Diagonal error weighting ``D`` (see the module docstring; 1 = none).
        cutoff_hz: Low-pass cut-off of the filtered basis (must match ``p_L``, ``u_L``).
        structure_interval: Samples between structure checks (>= 1).
        removal_time_s: Time over which an excluded wavelet's coefficient decays before removal.
        keep_seeds: Never exclude the initial ``2^d`` seed wavelets.
        update_structure: Grow/shrink the networks (False: fixed active set).

    """

    A_diag: tuple[float, ...]
    gamma: tuple[float, ...]
    bound_b: tuple[float, ...]
    inertia_kgm2: tuple[float, ...]
    cutoff_hz: float = DEFAULT_CUTOFF_HZ
    structure_interval: int = 10
    removal_time_s: float = 0.05
    keep_seeds: bool = True
    update_structure: bool = True

    def __post_init__(self) -> None:
        n = len(self.A_diag)
        for name in ("gamma", "bound_b", "inertia_kgm2"):
            if len(getattr(self, name)) != n:
                raise ConfigurationError(f"{name} needs {n} values")
        if not all(a < 0.0 and math.isfinite(a) for a in self.A_diag):
            raise ConfigurationError(f"A must be Hurwitz (diagonal < 0), got {self.A_diag}")
        for name in ("gamma", "bound_b", "inertia_kgm2"):
            if not all(v > 0.0 and math.isfinite(v) for v in getattr(self, name)):
                raise ConfigurationError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.cutoff_hz > 0.0:
            raise ConfigurationError(f"cutoff_hz must be > 0, got {self.cutoff_hz}")
        if int(self.structure_interval) != self.structure_interval or self.structure_interval < 1:
            raise ConfigurationError("structure_interval must be an integer >= 1")
        if not self.removal_time_s > 0.0:
            raise ConfigurationError("removal_time_s must be > 0")


@dataclass(frozen=True)
class AdaptationResult:
    """Summary of one :meth:`LyapunovAdapter.run` over a recording.

    Attributes:
        samples: Samples processed.
        duration_s: Recording duration.
        wall_time_s: Processing time; ``samples_per_s`` = samples / wall_time_s.
        size_times_s: Times at which the network sizes changed (first entry: start).
        network_sizes: Active wavelets per joint at those times (M x n).
        final_sizes: Active wavelets per joint at the end.
        prediction_error: Identifier error ``e = p_L - p_hat`` per sample (N x n) [N m s].
        error_rms: RMS of ``e`` over the run, per joint.
        final_error_rms: RMS of ``e`` over the last 10 % of the run, per joint.
        included, excluded: Wavelets added / removed per joint during the run.

    """

    samples: int
    duration_s: float
    wall_time_s: float
    size_times_s: np.ndarray
    network_sizes: np.ndarray
    final_sizes: tuple[int, ...]
    prediction_error: np.ndarray
    error_rms: np.ndarray
    final_error_rms: np.ndarray
    included: np.ndarray
    excluded: np.ndarray

    def __post_init__(self) -> None:
        if self.samples < 0 or self.prediction_error.shape[0] != self.samples:
            raise ConfigurationError("AdaptationResult: inconsistent sample count")
        if self.network_sizes.shape[0] != self.size_times_s.shape[0]:
            raise ConfigurationError("AdaptationResult: size history shapes differ")

    @property
    def samples_per_s(self) -> float:
        """Processing speed [samples/s]."""
        return self.samples / self.wall_time_s if self.wall_time_s > 0 else math.inf


class LyapunovAdapter:
    """On-line Lyapunov adaptation (with thresholding) of a wavelet network's coefficients."""

    def __init__(
        self,
        network: WaveletNetwork,
        A_diag: float | Sequence[float] = -300.0,
        gamma: float | Sequence[float] = (0.08, 0.05, 0.05),
        bound_B: float | Sequence[float] = 100.0,
        cutoff_hz: float = DEFAULT_CUTOFF_HZ,
        *,
        inertia_kgm2: float | Sequence[float] | np.ndarray = 1.0,
        structure_interval: int = 10,
        removal_time_s: float = 0.05,
        keep_seeds: bool = True,
        update_structure: bool = True,
        track_coverage: bool = True,
    ) -> None:
        """Attach to ``network`` (scalars are broadcast to every joint)."""
        n = network.n_joints
        self.network = network
        self.config = AdaptationConfig(
            A_diag=_per_joint("A_diag", A_diag, n),
            gamma=_per_joint("gamma", gamma, n),
            bound_b=_per_joint("bound_B", bound_B, n),
            inertia_kgm2=_per_joint("inertia_kgm2", inertia_kgm2, n),
            cutoff_hz=float(cutoff_hz),
            structure_interval=int(structure_interval),
            removal_time_s=float(removal_time_s),
            keep_seeds=bool(keep_seeds),
            update_structure=bool(update_structure),
        )
        self.track_coverage = bool(track_coverage)
        self._n = n
        self._A = np.asarray(self.config.A_diag)
        self._gain_joint = np.asarray(self.config.gamma) / np.asarray(self.config.inertia_kgm2)
        self._B = np.asarray(self.config.bound_b)
        self._omega = 2.0 * math.pi * self.config.cutoff_hz
        self._joint_inputs = np.full((n, max(2, network.pool.dmax)), -1, dtype=np.int64)
        for j, spec in enumerate(network.specs):
            self._joint_inputs[j, : spec.d] = spec.inputs
        self._decay_tau_s = self.config.removal_time_s / REMOVAL_TIME_CONSTANTS
        self._mu = np.asarray([s.mu for s in network.specs])
        self._theta = np.asarray([s.theta for s in network.specs])
        size = network.pool.size
        self._psi_l_pool = np.zeros(size)
        self._removal_left_pool = np.full(size, np.inf)
        self._prev_abs_pool = np.zeros(size)
        self._protected_pool = np.zeros(size, dtype=bool)
        if self.config.keep_seeds:
            self._protected_pool[network.pool.seeds] = True
        self.included = np.zeros(n, dtype=np.int64)
        self.excluded = np.zeros(n, dtype=np.int64)
        self._coverage_buffer: list[np.ndarray] = []
        self._size_history: list[tuple[float, tuple[int, ...]]] = []
        self._version = -1
        self.reset()

    # -- state -------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the signal states (identifier, filtered basis); keep coefficients/structure."""
        if self._version == self.network.structure_version:
            self._store()
        self._p_hat: np.ndarray | None = None
        self._psi_l_pool[:] = 0.0
        self._since_check = 0
        self._time_since_check = 0.0
        self._version = -1

    @property
    def p_hat(self) -> np.ndarray | None:
        """Identifier state ``p_hat`` (None before the first sample)."""
        return None if self._p_hat is None else self._p_hat.copy()

    def _load(self) -> None:
        """Gather the flat working arrays of the network's active set."""
        net = self.network
        pool = net.pool
        idx = net.active_global_indices()
        self._idx = idx
        self._joint = pool.joint[idx]
        self._amp = pool.amplitude[idx]
        self._c = net.coefficients_at(idx)
        self._psi_l = self._psi_l_pool[idx]
        self._removal_left = self._removal_left_pool[idx]
        self._decaying = np.isfinite(self._removal_left)
        self._prev_abs = self._prev_abs_pool[idx]
        self._protected = self._protected_pool[idx]
        self._gain = self._gain_joint[self._joint] * ~self._decaying
        self._step_arrays_version = -1  # built by _step_arrays when step() needs them
        bounds = np.searchsorted(self._joint, np.arange(self._n + 1))
        self._joint_start = bounds.astype(np.int64)
        self._inv = pool.inv_scale[idx]
        self._centre_scaled_t = np.ascontiguousarray(pool.centre_scaled[idx].T)
        self._any_decay = bool(np.any(self._decaying))
        self._version = net.structure_version

    def _step_arrays(self) -> None:
        """Build the block solver's arrays of the active set (:meth:`step`; not :meth:`run`)."""
        if self._step_arrays_version == self._version:
            return
        pool = self.network.pool
        idx = self._idx
        self._input_index = np.ascontiguousarray(pool.input_index[idx])
        self._centre_scaled = np.ascontiguousarray(pool.centre_scaled[idx])
        self._rows = np.arange(idx.size)
        self._onehot = np.zeros((idx.size, self._n))
        self._onehot[np.arange(idx.size), self._joint] = 1.0
        self._step_arrays_version = self._version

    def _store(self) -> None:
        """Scatter the flat working arrays back (coefficients into the network)."""
        idx = self._idx
        self.network.set_coefficients_at(idx, self._c)
        self._psi_l_pool[idx] = self._psi_l
        self._removal_left_pool[idx] = self._removal_left
        self._prev_abs_pool[idx] = self._prev_abs

    def _sync_in(self) -> None:
        if self._version != self.network.structure_version:
            if self._version >= 0:
                # structure changed outside the adapter (e.g. fit_batch): restart the
                # thresholding bookkeeping; filtered states of new wavelets start at 0
                self._removal_left_pool[:] = np.inf
                self._prev_abs_pool[:] = np.abs(
                    self.network.coefficients_at(np.arange(self.network.pool.size))
                )
            self._load()
        else:
            self._c = self.network.coefficients_at(self._idx)

    def _raw(self, qd: np.ndarray) -> np.ndarray:
        """Raw wavelet values of the active set for samples ``qd`` (K, n) -> (K, P).

        The one definition of the wavelet, :func:`~teleop_force.friction.terms.pool_wavelets`.
        """
        return pool_wavelets(
            np.ascontiguousarray(qd, dtype=float),
            self._input_index,
            self._centre_scaled,
            self._inv,
            self._amp,
        )

    # -- the recursion, one sample (step; run uses the compiled kernels.adapt_samples) --------

    def _advance(
        self, qd: np.ndarray, p_l: np.ndarray, u_l: np.ndarray, dt: np.ndarray
    ) -> np.ndarray:
        """Run one sample (arrays of one row) with a fixed structure; return ``e`` (1, n)."""
        self._step_arrays()
        raw = self._raw(qd)
        if self._p_hat is None:
            self._p_hat = np.array(p_l[0], dtype=float)
            self._psi_l = raw[0].copy()
        a = np.exp(-self._omega * dt)
        psi_l = a[0] * self._psi_l + (1.0 - a[0]) * raw
        if self._any_decay:
            c_dec = self._c * self._decaying
            s = psi_l @ (self._onehot * (self._c - c_dec)[:, None])
            s += psi_l @ (self._onehot * c_dec[:, None])
        else:
            s = psi_l @ (self._onehot * self._c[:, None])
        p_hat0 = self._p_hat
        e = p_l - p_hat0
        p_next = (1.0 + dt[0] * self._A) * p_hat0 + dt[0] * (u_l[0] - s[0] - self._A * p_l[0])
        projected = psi_l.T @ (dt[:, None] * e)  # (P, n): psi dt e
        delta = projected[self._rows, self._joint]
        delta *= -self._gain
        if self._any_decay:
            delta += c_dec * (np.exp(-dt[:1] / self._decay_tau_s)[0] - 1.0)
        c_new = self._c + delta
        norms = np.sqrt((c_new * c_new) @ self._onehot)
        if np.any(norms > self._B):
            scale = np.minimum(1.0, self._B / np.maximum(norms, 1e-300))
            c_new *= scale[self._joint]
        self._c = c_new
        self._psi_l = psi_l[-1].copy()
        self._p_hat = p_next
        self._time_since_check += float(dt[0])
        return e

    def _record_sizes(self, t_s: float) -> None:
        sizes = self.network.parameter_counts()
        if not self._size_history or self._size_history[-1][1] != sizes:
            self._size_history.append((t_s, sizes))

    def _update_structure(self, qd_now: np.ndarray) -> None:
        """Thresholding of Section III-D at the end of a block (vectorised)."""
        block_time = self._time_since_check
        self._since_check = 0
        self._time_since_check = 0.0
        if self._coverage_buffer:
            self._flush_coverage()
        if not self.config.update_structure:
            return
        absc = np.abs(self._c)
        decaying = self._decaying
        done = np.zeros_like(decaying)
        if self._any_decay:
            self._removal_left[decaying] -= block_time
            done = decaying & (self._removal_left <= 1e-9 * self.config.removal_time_s)
        newly = (
            ~decaying
            & ~self._protected
            & (absc < self._theta[self._joint])
            & (absc < self._prev_abs)
        )
        mu = self._mu[self._joint]
        trigger = ~decaying & (absc > mu) & (self._prev_abs <= mu)
        self._prev_abs = absc
        if np.any(newly):
            self._removal_left[newly] = self.config.removal_time_s
            self._decaying = self._decaying | newly
            self._gain[newly] = 0.0
            self._any_decay = True
        if np.any(done) or np.any(trigger):
            self._change_structure(done, trigger, qd_now)

    def _change_structure(self, done: np.ndarray, trigger: np.ndarray, qd_now: np.ndarray) -> None:
        """Remove the ``done`` wavelets, add the neighbours of the ``trigger`` ones (masks)."""
        net = self.network
        self._c[done] = 0.0
        self._store()
        removed = self._idx[done]
        if removed.size:
            self._removal_left_pool[removed] = np.inf
            self._prev_abs_pool[removed] = 0.0
            self._psi_l_pool[removed] = 0.0
            np.add.at(self.excluded, net.pool.joint[removed], 1)
            net.deactivate(removed)
        if np.any(trigger):
            candidates = net.pool.neighbours(self._idx[trigger])
            new = net.activate(candidates)
            if new.size:
                self._psi_l_pool[new] = net.pool.evaluate(qd_now[None, :], new)[0]
                self._removal_left_pool[new] = np.inf
                self._prev_abs_pool[new] = 0.0
                np.add.at(self.included, net.pool.joint[new], 1)
        self._load()

    def _flush_coverage(self) -> None:
        if self.network.coverage is not None and self._coverage_buffer:
            self.network.coverage.add(np.asarray(self._coverage_buffer))
        self._coverage_buffer.clear()

    def decaying_indices(self) -> np.ndarray:
        """Global indices of the wavelets currently being removed (coefficient decaying)."""
        self._sync_in()
        return self._idx[self._decaying].copy()

    # -- public API ----------------------------------------------------------------------------

    def step(
        self, qd_friction: np.ndarray, p_L: np.ndarray, u_L: np.ndarray, dt: float
    ) -> np.ndarray:
        """Process one sample; return the prediction error ``e = p_L - p_hat`` (n,).

        ``qd_friction`` are the motor velocities the networks read, ``p_L`` the filtered
        momentum, ``u_L`` the filtered motor torque minus the filtered rigid-body torque, ``dt``
        the time since the previous sample [s]. The network's coefficients are updated.
        """
        qd_arr = np.asarray(qd_friction, dtype=float).reshape(1, -1)
        p_arr = np.asarray(p_L, dtype=float).reshape(1, -1)
        u_arr = np.asarray(u_L, dtype=float).reshape(1, -1)
        for name, arr in (("qd_friction", qd_arr), ("p_L", p_arr), ("u_L", u_arr)):
            if arr.shape[1] != self._n:
                raise DataError(f"{name}: expected {self._n} values, got {arr.shape[1]}")
        if not dt > 0.0:
            raise DataError(f"sample interval must be > 0, got {dt}")
        self._sync_in()
        e = self._advance(qd_arr, p_arr, u_arr, np.asarray([float(dt)]))[0]
        if self.track_coverage:
            self._coverage_buffer.append(qd_arr[0])
        self._since_check += 1
        if self._since_check >= self.config.structure_interval:
            self._update_structure(qd_arr[0])
        self.network.set_coefficients_at(self._idx, self._c)
        return e

    def run(
        self,
        t_s: np.ndarray,
        qd: np.ndarray,
        p_L: np.ndarray,
        u_L: np.ndarray,
        *,
        reset: bool = True,
        dt_s: np.ndarray | None = None,
    ) -> AdaptationResult:
        """Adapt over a whole recording (N samples); ``reset`` first forgets signal states.

        ``dt_s``: the sample intervals (N, > 0) as :meth:`step` would get them (the first one
        since the previous call's last sample); default: from ``t_s``.
        """
        t_arr = np.asarray(t_s, dtype=float).reshape(-1)
        if dt_s is None:
            dt = regularised_intervals(t_arr)
        else:
            dt = np.ascontiguousarray(dt_s, dtype=float).reshape(-1)
            if dt.shape != t_arr.shape or not np.all(dt > 0.0):
                raise DataError(f"dt_s: expected {t_arr.size} intervals > 0")
        n_samples = t_arr.size
        arrays = []
        for name, value in (("qd", qd), ("p_L", p_L), ("u_L", u_L)):
            arr = np.asarray(value, dtype=float)
            if arr.shape != (n_samples, self._n):
                raise DataError(f"{name}: expected shape ({n_samples}, {self._n}), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise DataError(f"{name}: contains non-finite values")
            arrays.append(arr)
        qd_arr, p_arr, u_arr = arrays
        if reset:
            self.reset()
        from teleop_force.friction.kernels import adapt_samples  # numba: imported when used

        start_wall = time.perf_counter()
        included0, excluded0 = self.included.copy(), self.excluded.copy()
        self._size_history = []
        self._record_sizes(float(t_arr[0]))
        self._sync_in()
        if self.track_coverage and self.network.coverage is not None:
            self.network.coverage.add(qd_arr)
        if self._coverage_buffer:
            self._flush_coverage()
        errors = np.empty((n_samples, self._n))
        # the recursion and the threshold checks run compiled; Python takes over at the checks
        # that change the active set (neighbours, removal) and then resumes
        counters = np.array(
            [self._since_check, self._time_since_check, float(self._p_hat is not None), 0.0]
        )
        p_hat = np.zeros(self._n) if self._p_hat is None else self._p_hat.copy()
        start = 0
        while start < n_samples:
            done = np.zeros(self._idx.size, dtype=bool)
            trigger = np.zeros(self._idx.size, dtype=bool)
            start = adapt_samples(
                qd_arr, p_arr, u_arr, dt, start, errors, self._inv, self._centre_scaled_t,
                self._joint_inputs, self._amp, self._joint_start, self._protected, self._c,
                self._psi_l, self._gain, self._decaying, self._removal_left, self._prev_abs,
                self._A, self._B, self._mu, self._theta, self._omega, self._decay_tau_s,
                self.config.removal_time_s, self.config.structure_interval,
                self.config.update_structure, counters, p_hat, done, trigger,
            )  # fmt: skip
            self._since_check = int(counters[0])
            self._time_since_check = float(counters[1])
            self._p_hat = p_hat.copy() if counters[2] else None
            self._any_decay = bool(np.any(self._decaying))
            if counters[3]:
                counters[3] = 0.0
                self._change_structure(done, trigger, qd_arr[start - 1])
                self._record_sizes(float(t_arr[start - 1]))
        self.network.set_coefficients_at(self._idx, self._c)
        self._record_sizes(float(t_arr[-1]))
        wall = time.perf_counter() - start_wall
        tail = errors[int(0.9 * n_samples) :]
        times = np.asarray([h[0] for h in self._size_history])
        sizes = np.asarray([h[1] for h in self._size_history], dtype=np.int64).reshape(-1, self._n)
        return AdaptationResult(
            samples=n_samples,
            duration_s=float(t_arr[-1] - t_arr[0]),
            wall_time_s=wall,
            size_times_s=times,
            network_sizes=sizes,
            final_sizes=self.network.parameter_counts(),
            prediction_error=errors,
            error_rms=np.sqrt(np.mean(errors**2, axis=0)),
            final_error_rms=np.sqrt(np.mean(tail**2, axis=0)),
            included=self.included - included0,
            excluded=self.excluded - excluded0,
        )
