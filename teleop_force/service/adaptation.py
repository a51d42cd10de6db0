"""Online Lyapunov adaptation of a wavelet-network friction inside the running service.

When the service's model has a :class:`~teleop_force.friction.wavelet_network.WaveletNetwork`
friction, its :class:`~teleop_force.friction.adaptation.LyapunovAdapter` is fed the
identifier's signals (see that module)::

    q_v, qd = L_v(q), backward difference of q_v         pre-filtered angles and velocity
    p_L = L(M(q_v) qd)                                   filtered generalized momentum
    u_L = L(L_v(tau))[k - lag] - L(-C^T qd + N + tau_spring + offsets [+ CV(qd)])

(``CV(qd)``: ``WaveletNetwork.base_torque``, the coupled CV of a network that adds to it;
with a sticking state its Coulomb terms follow ``q_v``, the state carried across batches)

computed exactly as :class:`~teleop_force.estimation.estimator.ForceEstimator` computes its
terms (same pre-filter ``L_v``, cut-offs, torque lag and rigid-body model).

Off the 1 kHz path
------------------
:class:`AdaptationWorker` is what the service runs. The Zenoh receive thread only appends the
sample ``(t_s, q, tau, F)`` (tuples it already has, ``F`` the estimate's tip force) to a
bounded deque (:meth:`AdaptationWorker.submit`, a few hundred ns). A worker thread, one per
service, started when adaptation is switched on and stopped on off / model load / service
close, takes what is queued every ``period_s`` (50 ms) in one go and computes the signals of
the whole batch compiled (the pre-filter and low-pass recursions in numba with their states
carried across batches, the rigid body by :func:`~teleop_force.estimation.rigid_chain.
chain_terms_batch`), then runs :meth:`LyapunovAdapter.run` (compiled loop, ``reset=False``)
on a *private copy* of the network. The estimator's own network is never touched by the
worker: the worker posts a snapshot (active set, coefficients, the adapted velocities for the
coverage map) once per batch, and the receive thread installs the newest snapshot at its next
sample (:meth:`AdaptationWorker.apply`, under the service's lock, where the estimator is read
anyway), so the estimator's fused step repacks its network tables at ~20 Hz, not 1 kHz.
The adapted velocities reach the estimator's coverage map at most once a second
(``COVERAGE_PERIOD_S``: a coverage update makes the estimator rebuild its trust tables,
~0.5 ms). The worker's compiled kernels release the GIL; its Python glue (array building,
the adapter's structure changes) holds it for well under a millisecond per batch, which is
what the receive thread can wait for (``batch_ms`` in the statistics: the worker's time per
batch).
The result equals :class:`OnlineAdaptation` (the per-sample reference, kept for tests and
tools) fed the same samples and the same gate decisions, to rounding (tests: 1e-9).

Free-motion gate
----------------
Adaptation assumes the arm moves *freely*: an external force is indistinguishable from
friction and would be learnt as such. So a sample is adapted on only if

* the estimated tip force magnitude is below ``force_threshold_n`` (default 0.5 N; a NaN force,
  near a singularity, counts as contact), and
* no contact sample lies within ``guard_s`` (default 0.3 s) *before* it (contact ends are
  transients: the filters and the operator's release) and none within ``guard_s`` *after* it
  (a contact's onset is detected late, the force builds up through the filters). The
  look-ahead is causal because the worker holds each sample's signals back until ``guard_s``
  of stream time has followed it (or its stream ended); adaptation therefore lags the stream by
  ``guard_s`` + one period. On switch-off the held-back tail is judged on what was seen.

Gated-out samples still advance the signal filters (``p_L``, ``u_L`` need their history);
the identifier (``p_hat``, filtered basis) restarts at the first free sample after a gap, as
at a stream start. They are counted as ``skipped_contact`` in the ``adaptation`` statistics.
The gate is judged on the estimate of the model *being adapted*; a friction error large
enough to read as 0.5 N keeps that motion out of adaptation (it shows as ``skipped_contact``).
"""

from __future__ import annotations

import copy
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.estimation.rigid_chain import chain_tables, chain_terms_batch
from teleop_force.friction.adaptation import LyapunovAdapter
from teleop_force.friction.terms import sticking_friction_torque, sticking_states_into
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.lowpass import LowPass

#: Tip-force magnitude [N] at or above which a sample counts as contact (not adapted on).
DEFAULT_FORCE_THRESHOLD_N = 0.5
#: Samples within this time [s] of a contact sample (either side) are not adapted on.
DEFAULT_GUARD_S = 0.3
#: The worker processes its queue this often [s].
DEFAULT_PERIOD_S = 0.05
#: Samples the receive path may queue before the oldest are dropped (counted).
QUEUE_CAPACITY = 20_000
#: The worker thread is waited for at most this long when stopped [s].
STOP_TIMEOUT_S = 5.0
#: The adapted velocities reach the estimator's coverage map at most this often [s] (a coverage
#: update makes the estimator rebuild its trust tables, ~0.5 ms in the receive thread).
COVERAGE_PERIOD_S = 1.0
#: Interval given to the first sample of a stream (as :class:`OnlineAdaptation` does).
_FIRST_DT_S = 1e-3
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class AdaptationGate:
    """Which samples online adaptation learns from (module docstring, "Free-motion gate").

    Attributes:
        force_threshold_n: Tip-force magnitude at or above which a sample is contact [N].
        guard_s: Samples within this stream time of a contact sample, either side, are skipped.

    """

    force_threshold_n: float = DEFAULT_FORCE_THRESHOLD_N
    guard_s: float = DEFAULT_GUARD_S

    def __post_init__(self) -> None:
        if not (math.isfinite(self.force_threshold_n) and self.force_threshold_n > 0.0):
            raise ConfigurationError(f"force_threshold_n must be > 0, got {self.force_threshold_n}")
        if not (math.isfinite(self.guard_s) and self.guard_s >= 0.0):
            raise ConfigurationError(f"guard_s must be >= 0, got {self.guard_s}")


def adaptation_unavailable_reason(estimator: ForceEstimator) -> str | None:
    """Why the estimator's model cannot be adapted online (``None``: it can)."""
    friction = estimator.model.friction
    if not isinstance(friction, WaveletNetwork):
        return f"the model's friction is {friction.kind!r}; online adaptation needs 'wn'"
    if estimator.robot is None:
        return "the model has no rigid-body terms (robot 'none'): no momentum to adapt on"
    return None


class _StickingBase:
    """The fallback's torque a network on its fallback adds to, its Coulomb terms sticking.

    What :meth:`WaveletNetwork.base_torque` gives, with the fallback's sticking state
    (``sticking_rad``) advanced along the adaptation's pre-filtered angles: the network's
    target is then what the estimator's fallback leaves. ``state`` carries over between
    calls; a stream begins at a ``first`` sample.
    """

    def __init__(self, network: WaveletNetwork) -> None:
        fallback = network.fallback
        assert fallback is not None and fallback.sticking_rad > 0.0
        rows, reach = fallback.term_table()
        self.rows = np.ascontiguousarray(rows, dtype=float)
        self.reach = np.ascontiguousarray(reach, dtype=float)
        self.parameters = fallback.parameters
        self.inv_transition = 1.0 / fallback.sticking_rad
        self.state = np.zeros(1 + 2 * self.rows.shape[0])

    @staticmethod
    def of(network: WaveletNetwork) -> _StickingBase | None:
        """Return the sticking base of ``network``; None unless it adds to a sticking fallback."""
        fallback = network.fallback
        if not network.on_fallback or fallback is None or not fallback.sticking_rad > 0.0:
            return None
        return _StickingBase(network)

    def torques(self, q: np.ndarray, qd: np.ndarray, first: np.ndarray) -> np.ndarray:
        """Torque (m, n) at the samples' angles and velocities (m, n), in stream order."""
        z = sticking_states_into(
            np.ascontiguousarray(q), self.rows, self.inv_transition, first, self.state
        )
        return sticking_friction_torque(
            np.ascontiguousarray(qd), self.rows, self.reach, self.parameters, z
        )


def _make_adapter(
    estimator: ForceEstimator, network: WaveletNetwork, *, track_coverage: bool
) -> LyapunovAdapter:
    """Return the service's adapter of ``network`` (gains of the estimator's model, robot)."""
    robot = estimator.robot
    assert robot is not None  # adaptation_unavailable_reason checked it
    config = estimator.model.filter_config
    mid = 0.5 * (robot.description.q_min_rad + robot.description.q_max_rad)
    inertia = np.diag(robot.mass_matrix(mid))
    return LyapunovAdapter(
        network,
        cutoff_hz=config.cutoff_hz,
        inertia_kgm2=tuple(inertia.tolist()),
        track_coverage=track_coverage,
    )


def _check(estimator: ForceEstimator) -> WaveletNetwork:
    reason = adaptation_unavailable_reason(estimator)
    if reason is not None:
        raise ConfigurationError(reason)
    network = estimator.model.friction
    assert isinstance(network, WaveletNetwork)
    return network


class OnlineAdaptation:
    """Per-sample driver of a :class:`LyapunovAdapter` on a joint-state stream (the reference).

    Adapts the estimator's own network in place, one :meth:`LyapunovAdapter.step` per free
    sample; :class:`AdaptationWorker` (what the service runs) gives the same result in batches.
    """

    def __init__(self, estimator: ForceEstimator) -> None:
        """Attach to ``estimator``'s wavelet-network friction; raise ConfigurationError."""
        network = _check(estimator)
        robot = estimator.robot
        assert robot is not None
        self.estimator = estimator
        self.robot = robot
        config = estimator.model.filter_config
        self.adapter = _make_adapter(estimator, network, track_coverage=True)
        self._lag = config.torque_lag_samples
        self._angle = LowPass(config.velocity_cutoff_hz)
        self._torque_prefilter = LowPass(config.velocity_cutoff_hz)
        self._momentum = LowPass(config.cutoff_hz)
        self._torque = LowPass(config.cutoff_hz)
        self._rigid = LowPass(config.cutoff_hz)
        self._t_prev: float | None = None
        self._q_prev = np.zeros(estimator.n)
        self._gap = True
        self._sticking = _StickingBase.of(network)
        self.samples = 0
        self.skipped = 0
        self.last_error = np.zeros(estimator.n)

    def reset(self) -> None:
        """Forget the signal states (a new stream begins); coefficients are kept."""
        for f in (self._angle, self._torque_prefilter, self._momentum, self._torque, self._rigid):
            f.reset()
        self._t_prev = None
        self._gap = True
        self.adapter.reset()

    def update(self, t_s: float, q_rad: np.ndarray, tau_nm: np.ndarray, free: bool = True) -> None:
        """Feed one sample (same inputs as :meth:`ForceEstimator.update`).

        ``free``: the gate's decision; a sample that is not free advances the signal filters
        only, and the identifier restarts at the next free sample.
        """
        q_raw = np.asarray(q_rad, dtype=float)
        tau = np.asarray(tau_nm, dtype=float)
        dt = _FIRST_DT_S if self._t_prev is None else t_s - self._t_prev
        if not dt > 0.0:
            self.reset()
            dt = _FIRST_DT_S
        first = self._t_prev is None
        q = self._angle.update(q_raw, dt).copy()
        qd = np.zeros_like(q) if first else (q - self._q_prev) / dt
        self._t_prev = t_s
        self._q_prev = q
        robot = self.robot
        p_l = self._momentum.update(robot.momentum(q, qd), dt)
        sticking = self._sticking
        base = (
            self.adapter.network.base_torque(qd)[0]
            if sticking is None
            else sticking.torques(q[None, :], qd[None, :], np.array([first]))[0]
        )
        rigid = (
            robot.coriolis_transpose_gravity(q, qd)
            + robot.spring_torque(q, self.estimator.spring_stiffness)
            + self.estimator.model.offsets_nm
            + base
        )
        rigid_l = self._rigid.update(rigid, dt)
        previous = self._torque.state
        previous = None if previous is None else previous.copy()
        tau_now = self._torque.update(self._torque_prefilter.update(tau, dt), dt)
        tau_l = tau_now if (self._lag == 0 or previous is None) else previous
        if not free:
            self._gap = True
            self.skipped += 1
            return
        if self._gap:
            self.adapter.reset()
            self._gap = False
        self.last_error = self.adapter.step(qd, p_l, tau_l - rigid_l, dt)
        self.samples += 1


# -- compiled batch kernels ------------------------------------------------------------------


@njit_cached()
def _prefilter_signals(
    t: np.ndarray,
    q: np.ndarray,
    restart: np.ndarray,
    state: np.ndarray,
    omega_v: float,
    q_v: np.ndarray,
    qd: np.ndarray,
    dt: np.ndarray,
    first: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``L_v(q)``, its backward difference, ``dt`` and stream starts, state carried over.

    ``state``: ``[started, t_prev, q_v (n), ...]`` (:class:`AdaptationWorker`). A stream starts
    at a ``restart`` sample, at the first sample ever and where time does not increase.
    """
    n_samples, n = q.shape
    for k in range(n_samples):
        step = t[k] - state[1]
        if state[0] == 0.0 or restart[k] or not step > 0.0:
            first[k] = True
            dt[k] = _FIRST_DT_S
            for i in range(n):
                q_v[k, i] = q[k, i]
                qd[k, i] = 0.0
                state[2 + i] = q[k, i]
            state[0] = 1.0
        else:
            first[k] = False
            dt[k] = step
            a = math.exp(-omega_v * step)
            for i in range(n):
                previous = state[2 + i]
                value = a * previous + (1.0 - a) * q[k, i]
                q_v[k, i] = value
                qd[k, i] = (value - previous) / step
                state[2 + i] = value
        state[1] = t[k]


@njit_cached()
def _filter_signals(
    tau: np.ndarray,
    momentum: np.ndarray,
    rigid: np.ndarray,
    first: np.ndarray,
    dt: np.ndarray,
    state: np.ndarray,
    omega_v: float,
    omega: float,
    lag: int,
    p_l: np.ndarray,
    u_l: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``p_L`` and ``u_L`` of every sample (the identifier's inputs), state carried over.

    ``state`` after the pre-filter's ``2 + n``: ``L_v(tau)``, ``p_L``, ``L(rigid)``, ``tau_L``.
    """
    n_samples, n = tau.shape
    o_tv, o_p, o_r, o_t = 2 + n, 2 + 2 * n, 2 + 3 * n, 2 + 4 * n
    for k in range(n_samples):
        if first[k]:
            for i in range(n):
                state[o_tv + i] = tau[k, i]
                state[o_t + i] = tau[k, i]
                state[o_p + i] = momentum[k, i]
                state[o_r + i] = rigid[k, i]
                p_l[k, i] = momentum[k, i]
                u_l[k, i] = tau[k, i] - rigid[k, i]
            continue
        a_v = math.exp(-omega_v * dt[k])
        a = math.exp(-omega * dt[k])
        for i in range(n):
            tau_v = a_v * state[o_tv + i] + (1.0 - a_v) * tau[k, i]
            state[o_tv + i] = tau_v
            previous = state[o_t + i]
            now = a * previous + (1.0 - a) * tau_v
            state[o_t + i] = now
            p = a * state[o_p + i] + (1.0 - a) * momentum[k, i]
            state[o_p + i] = p
            r = a * state[o_r + i] + (1.0 - a) * rigid[k, i]
            state[o_r + i] = r
            p_l[k, i] = p
            u_l[k, i] = (now if lag == 0 else previous) - r


@njit_cached()
def _gate(
    t: np.ndarray,
    contact: np.ndarray,
    first: np.ndarray,
    guard_s: float,
    final: bool,
    state: np.ndarray,
    free: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Decide the leading samples whose guard window is known; return how many.

    ``free[k]``: not contact and no contact sample of the same stream within ``guard_s``
    either side. A sample is decided once ``guard_s`` of its stream followed it, a contact
    within ``guard_s`` after it was seen, its stream ended, or ``final``. ``state[0]``: time of
    the last contact sample decided (-inf: none in this stream).
    """
    n = t.size
    if n == 0:
        return 0
    next_contact = np.empty(n)
    ended = np.empty(n, dtype=np.bool_)
    newest = np.empty(n)
    upcoming = math.inf
    end = final
    latest = t[n - 1]
    for k in range(n - 1, -1, -1):
        if contact[k]:
            upcoming = t[k]
        next_contact[k] = upcoming
        ended[k] = end
        newest[k] = latest
        if first[k]:  # the samples before k belong to a stream that ended
            upcoming = math.inf
            end = True
            if k > 0:
                latest = t[k - 1]
    last = state[0]
    ready = 0
    for k in range(n):
        if not (ended[k] or next_contact[k] - t[k] <= guard_s or newest[k] - t[k] >= guard_s):
            break
        if first[k]:
            last = -math.inf
        if contact[k]:
            last = t[k]
            free[k] = False
        else:
            free[k] = t[k] - last > guard_s and next_contact[k] - t[k] > guard_s
        ready = k + 1
    state[0] = last
    return ready


def free_mask(
    t_s: np.ndarray, contact: np.ndarray, stream_start: np.ndarray, guard_s: float
) -> np.ndarray:
    """Return the gate's decisions over a whole stream (the worker's, sample by sample).

    ``contact``: the force is at or above the threshold (or NaN); ``stream_start``: a new
    stream begins at the sample.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    free = np.zeros(t.size, dtype=bool)
    state = np.array([-math.inf])
    _gate(
        t, np.ascontiguousarray(contact, dtype=bool),
        np.ascontiguousarray(stream_start, dtype=bool), float(guard_s), True, state, free,
    )  # fmt: skip
    return free


def _summary_ms(durations_s: list[float]) -> dict[str, float] | None:
    """p50 / p99 / max of the last batch times [ms] (None before the first)."""
    if not durations_s:
        return None
    ms = np.asarray(durations_s) * 1e3
    return {
        "p50": round(float(np.percentile(ms, 50)), 4),
        "p99": round(float(np.percentile(ms, 99)), 4),
        "max": round(float(ms.max()), 4),
    }


@dataclass(frozen=True)
class _Snapshot:
    """What a batch posts for the estimator: the private network's state, the new coverage."""

    structure_version: int
    indices: np.ndarray
    coefficients: np.ndarray
    coverage_qd: np.ndarray


class _Pending:
    """Signals of samples the gate has not decided yet (columns of equal length)."""

    def __init__(self, n: int) -> None:
        self.t = np.zeros(0)
        self.dt = np.zeros(0)
        self.first = np.zeros(0, dtype=bool)
        self.contact = np.zeros(0, dtype=bool)
        self.qd = np.zeros((0, n))
        self.p_l = np.zeros((0, n))
        self.u_l = np.zeros((0, n))

    def extend(self, **columns: np.ndarray) -> None:
        for name, value in columns.items():
            setattr(self, name, np.concatenate((getattr(self, name), value)))

    def take(self, count: int) -> dict[str, np.ndarray]:
        names = ("t", "dt", "first", "contact", "qd", "p_l", "u_l")
        out = {name: getattr(self, name)[:count] for name in names}
        for name in names:
            setattr(self, name, getattr(self, name)[count:])
        return out

    def __len__(self) -> int:
        return int(self.t.size)


class AdaptationWorker:
    """Online adaptation of the service's estimator off the receive path (module docstring).

    Thread roles: :meth:`submit`, :meth:`reset` and :meth:`apply` are called by the service
    with its lock held (the receive thread, a control); :meth:`drain` runs in the worker thread
    (or directly, in tests); :meth:`start` / :meth:`stop` by the service's controls.
    """

    def __init__(
        self,
        estimator: ForceEstimator,
        gate: AdaptationGate | None = None,
        *,
        period_s: float = DEFAULT_PERIOD_S,
    ) -> None:
        """Copy ``estimator``'s network and prepare the adapter; raise ConfigurationError."""
        target = _check(estimator)
        robot = estimator.robot
        assert robot is not None
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ConfigurationError(f"period_s must be > 0, got {period_s}")
        self.estimator = estimator
        self.gate = gate if gate is not None else AdaptationGate()
        self.period_s = float(period_s)
        self.target = target
        self.network = copy.deepcopy(target)  # the worker's own; the estimator's is never shared
        self.adapter = _make_adapter(estimator, self.network, track_coverage=False)
        n = estimator.n
        self.n = n
        config = estimator.model.filter_config
        self._lag = int(config.torque_lag_samples)
        self._omega_v = _TWO_PI * config.velocity_cutoff_hz
        self._omega = _TWO_PI * config.cutoff_hz
        self.robot = robot
        self._coupling = np.ascontiguousarray(robot.coupling, dtype=float)
        self._identity = self._coupling.shape[0] == n and bool(
            np.array_equal(self._coupling, np.eye(n))
        )
        self._rotor = np.asarray(robot.description.rotor_inertia_kgm2, dtype=float)
        self._offsets = np.asarray(estimator.model.offsets_nm, dtype=float)
        self._tables = chain_tables(robot.model, robot.description.tip_frame)
        self._queue: deque[tuple[Any, ...] | None] = deque(maxlen=QUEUE_CAPACITY)
        self._outbox: deque[_Snapshot] = deque()
        self._signal_state = np.zeros(2 + 5 * n)
        self._sticking = _StickingBase.of(self.network)
        self._gate_state = np.array([-math.inf])
        self._pending = _Pending(n)
        self._restart_next = True
        self._gap = True
        self._applied_structure = target.structure_version
        self._coverage_qd: list[np.ndarray] = []
        self._coverage_posted_s = time.perf_counter()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._flush_on_stop = True
        self.submitted = 0  # receive path
        self.markers = 0  # receive path
        self.taken = 0  # worker
        self.samples = 0
        self.skipped_contact = 0
        self.batches = 0
        self.publications = 0
        self.errors = 0
        self.last_error = ""
        self._batch_s: deque[float] = deque(maxlen=1000)  # the worker's batch times
        self._warm_up()

    def _warm_up(self) -> None:
        """Load the compiled kernels now, not in the first batch (the coefficients stay)."""
        n = self.n
        one = np.zeros((1, n))
        self._signals([(0.0, (0.0,) * n, (0.0,) * n, 0.0, 0.0, 0.0)], np.ones(1, dtype=bool))
        free = np.zeros(1, dtype=bool)
        _gate(np.zeros(1), free, free, 0.0, True, np.array([-math.inf]), free)
        self.adapter.run(np.zeros(1), one, one, one, reset=True, dt_s=np.full(1, _FIRST_DT_S))
        self.adapter.reset()
        self._begin_stream()

    # -- receive path (service lock held) -------------------------------------------------

    def submit(self, t_s: float, q: Any, tau: Any, out: Any) -> None:
        """Queue one estimated sample: time, angles, torques (tuples), ``out[:3]`` the force.

        Installs the worker's newest snapshot first, if one is waiting.
        """
        self._queue.append((t_s, q, tau, out[0], out[1], out[2]))
        self.submitted += 1
        if self._outbox:
            self.apply()

    def reset(self) -> None:
        """Mark a stream restart: a new stream begins with the next sample submitted."""
        self._queue.append(None)
        self.markers += 1

    def apply(self) -> None:
        """Install the newest snapshot in the estimator's network (service lock held)."""
        outbox = self._outbox
        latest = None
        coverage = self.target.coverage
        while outbox:
            snapshot = outbox.popleft()
            if coverage is not None and snapshot.coverage_qd.shape[0]:
                coverage.add(snapshot.coverage_qd)
            latest = snapshot
        if latest is None:
            return
        target = self.target
        if latest.structure_version != self._applied_structure:
            joint = target.pool.joint[latest.indices]
            for j in range(self.n):
                mine = joint == j
                target.set_structure(j, latest.indices[mine], latest.coefficients[mine])
            self._applied_structure = latest.structure_version
        else:
            target.set_coefficients_at(latest.indices, latest.coefficients)
        self.publications += 1

    # -- lifetime ---------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """Whether the worker thread runs."""
        return self._thread is not None

    def start(self) -> None:
        """Start the worker thread on a fresh stream (no-op if it runs)."""
        if self._thread is not None:
            return
        self._queue.clear()
        self._begin_stream()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="adaptation", daemon=True)
        self._thread.start()

    def stop(self, *, flush: bool = True) -> None:
        """Stop the worker thread; ``flush``: adapt on what is queued first (then :meth:`apply`).

        Safe with the service's lock held: the worker never takes it.
        """
        thread = self._thread
        if thread is None:
            return
        self._flush_on_stop = flush
        self._stop.set()
        thread.join(STOP_TIMEOUT_S)
        self._thread = None

    def _begin_stream(self) -> None:
        self._restart_next = True
        self._signal_state[:] = 0.0
        if self._sticking is not None:
            self._sticking.state[:] = 0.0
        self._gate_state[0] = -math.inf
        self._pending = _Pending(self.n)
        self._gap = True

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._drain_guarded(final=False)
        if self._flush_on_stop:
            self._drain_guarded(final=True)

    def _drain_guarded(self, *, final: bool) -> None:
        started_s = time.perf_counter()
        try:
            self.drain(final=final)
        except Exception as exc:  # the worker must not die; the stream starts afresh
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            self._begin_stream()
        self._batch_s.append(time.perf_counter() - started_s)

    # -- the worker's batch -----------------------------------------------------------------

    def drain(self, *, final: bool = False) -> int:
        """Process everything queued; ``final``: decide the held-back tail too. Return adapted."""
        items = []
        queue = self._queue
        while True:
            try:
                items.append(queue.popleft())
            except IndexError:
                break
        rows = []
        restarts = []
        restart = self._restart_next
        for item in items:
            if item is None:
                restart = True
                continue
            rows.append(item)
            restarts.append(restart)
            restart = False
        self._restart_next = restart
        self.taken += len(items)
        if rows:
            self._signals(rows, np.asarray(restarts, dtype=bool))
        adapted = self._adapt_decided(final)
        self.batches += 1
        return adapted

    def _signals(self, rows: list[tuple[Any, ...]], restart: np.ndarray) -> None:
        """Compute the batch's identifier signals and append them to the pending ones."""
        m, n = len(rows), self.n
        t = np.fromiter((r[0] for r in rows), dtype=float, count=m)
        q = np.array([r[1] for r in rows], dtype=float).reshape(m, n)
        tau = np.array([r[2] for r in rows], dtype=float).reshape(m, n)
        force = np.array([r[3:6] for r in rows], dtype=float).reshape(m, 3)
        norm = np.sqrt(np.sum(force * force, axis=1))
        contact = ~(norm < self.gate.force_threshold_n)  # NaN counts as contact
        q_v, qd = np.empty((m, n)), np.empty((m, n))
        dt, first = np.empty(m), np.empty(m, dtype=bool)
        _prefilter_signals(t, q, restart, self._signal_state, self._omega_v, q_v, qd, dt, first)
        momentum, rigid = self._rigid_terms(q_v, qd, first)
        p_l, u_l = np.empty((m, n)), np.empty((m, n))
        _filter_signals(
            tau, momentum, rigid, first, dt, self._signal_state, self._omega_v, self._omega,
            self._lag, p_l, u_l,
        )  # fmt: skip
        self._pending.extend(t=t, dt=dt, first=first, contact=contact, qd=qd, p_l=p_l, u_l=u_l)

    def _rigid_terms(
        self, q_v: np.ndarray, qd: np.ndarray, first: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``M(q_v) qd`` and what the network is not fitted to, in motor coordinates.

        ``-C^T qd + N + springs + offsets``, plus the coupled CV of a network on its fallback
        (its sticking state, if any, advanced over the samples; ``first``: stream starts).
        """
        momentum, other = self._chain_terms(q_v, qd)
        sticking = self._sticking
        if sticking is None:
            return momentum, other + self.network.base_torque(qd)
        return momentum, other + sticking.torques(q_v, qd, first)

    def _chain_terms(self, q_v: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``M(q_v) qd`` and ``-C^T qd + N + springs + offsets`` in motor coordinates."""
        robot = self.robot
        tables = self._tables
        if tables is None:  # joints the compiled chain lacks: pinocchio, sample by sample
            stiffness = self.estimator.spring_stiffness
            momentum = np.array([robot.momentum(a, b) for a, b in zip(q_v, qd, strict=True)])
            other = np.array(
                [
                    robot.coriolis_transpose_gravity(a, b) + robot.spring_torque(a, stiffness)
                    for a, b in zip(q_v, qd, strict=True)
                ]
            ).reshape(q_v.shape)
            return momentum.reshape(q_v.shape), other + self._offsets
        coupling = self._coupling
        if self._identity:
            p_model, w_model = chain_terms_batch(q_v, qd, *tables.arrays())
            momentum, other = p_model + self._rotor * qd, w_model
        else:
            q_model = np.ascontiguousarray(q_v @ coupling.T)
            v_model = np.ascontiguousarray(qd @ coupling.T)
            p_model, w_model = chain_terms_batch(q_model, v_model, *tables.arrays())
            momentum, other = p_model @ coupling + self._rotor * qd, w_model @ coupling
        springs = robot.description.springs
        if springs:
            stiffness = self.estimator.spring_stiffness
            for s, k in zip(springs, stiffness, strict=True):
                other[:, s.joint] += k * (q_v[:, s.joint] - s.rest_angle_rad)
        return momentum, other + self._offsets

    def _adapt_decided(self, final: bool) -> int:
        """Gate the pending samples whose guard window is known and adapt on the free ones."""
        pending = self._pending
        free = np.zeros(len(pending), dtype=bool)
        ready = _gate(
            pending.t, pending.contact, pending.first, self.gate.guard_s, final,
            self._gate_state, free,
        )  # fmt: skip
        if ready == 0 and not (final and self._coverage_qd):
            return 0
        batch = pending.take(ready)
        free = free[:ready]
        starts = batch["first"]
        adapter = self.adapter
        adapted = 0
        k = 0
        gap = self._gap
        while k < ready:
            if starts[k]:
                gap = True
            if not free[k]:
                gap = True
                k += 1
                continue
            end = k + 1
            while end < ready and free[end] and not starts[end]:
                end += 1
            if gap:
                adapter.reset()
                gap = False
            adapter.run(
                batch["t"][k:end], batch["qd"][k:end], batch["p_l"][k:end], batch["u_l"][k:end],
                reset=False, dt_s=batch["dt"][k:end],
            )  # fmt: skip
            adapted += end - k
            k = end
        self._gap = gap
        self.samples += adapted
        self.skipped_contact += ready - int(np.count_nonzero(free))
        if adapted:
            self._coverage_qd.append(batch["qd"][free])
        now_s = time.perf_counter()
        post_coverage = bool(self._coverage_qd) and (
            final or now_s - self._coverage_posted_s >= COVERAGE_PERIOD_S
        )
        if adapted or post_coverage:
            coverage_qd = np.zeros((0, self.n))
            if post_coverage:
                coverage_qd = np.concatenate(self._coverage_qd)
                self._coverage_qd = []
                self._coverage_posted_s = now_s
            network = self.network
            indices = network.active_global_indices()
            self._outbox.append(
                _Snapshot(
                    network.structure_version, indices, network.coefficients_at(indices),
                    coverage_qd,
                )
            )  # fmt: skip
        return adapted

    def stats(self) -> dict[str, Any]:
        """Counters of the ``adaptation`` statistics."""
        queued = len(self._queue)
        return {
            "samples": self.samples,
            "skipped_contact": self.skipped_contact,
            "pending": len(self._pending) + queued,
            "dropped": max(0, self.submitted + self.markers - self.taken - queued),
            "batches": self.batches,
            "publications": self.publications,
            "errors": self.errors,
            "last_error": self.last_error,
            "batch_ms": _summary_ms(list(self._batch_s)),
            "force_threshold_n": self.gate.force_threshold_n,
            "guard_s": self.gate.guard_s,
        }
