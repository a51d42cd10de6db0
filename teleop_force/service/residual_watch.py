"""The live residual watch: does the external torque in free motion start to depend on a variable.

With a model that fits, the estimated external torque ``tau_ext`` is noise plus the model's
own, steady misfit whenever the tip touches nothing. When the arm changes during a session (a
payload, a worn cable, warmer motors: something the model does not have), ``tau_ext`` in free
motion acquires a dependence on a variable. The watch tests for that, per joint, on what a real
slave publishes and the service computes (never on a simulator's truth): the joint angles
``q`` and motor torques (JointState), the force ``F``, ``tau_ext`` and low-passed motor
torque of an estimate, and time. In the service the estimate tested is the watch's own
(:class:`~teleop_force.service.watch_residual.WatchResidual`): the model's, always with the
estimator the thresholds below were calibrated on (the observer at 24 Hz on one stage at
``L_v``), made from the joint states in the watch's thread, whatever estimator the forces
are published with; without one, the published estimates (ForceEstimate) are tested.

Hot path: the service's receive callback only calls :meth:`ResidualWatch.append` with the two
payloads it already has (the joint state received, the estimate published): two reference
stores into preallocated slots of a ring (:class:`PayloadRing`; bytes objects are not tracked
by the garbage collector). Everything else runs in the watch's own thread every
:attr:`WatchConfig.period_s` (1 s), which decodes the new payloads in bulk with NumPy and
runs its estimator on them (compiled, in one batch).

Free motion (from the estimate tested, never the truth): a sample is *free* when its tip force is
finite and below :attr:`WatchConfig.free_force_n` (0.5 N), and no sample within
:attr:`WatchConfig.guard_s` (0.15 s) on either side is above it or singular (contact and its
transients are left out); joint ``j``'s rows are the free ones at which joint ``j`` moves
faster than :attr:`WatchConfig.min_speed_rad_s` (0.08 rad/s: its friction's sign is defined,
away from the pre-sliding regime no model here describes), and none within
:attr:`WatchConfig.settle_s` of a stream (re)start. Rows are taken at
:attr:`WatchConfig.decimate_hz` (50 Hz); each row's ``tau_ext`` is the mean over its 20 ms
(anti-aliasing: a point sample would keep the estimate's noise above 25 Hz, which is most of
it on the Omni's base joint). Velocities and accelerations are central differences of ``q``
(over 20 and 50 ms): the watch uses the angles, not the published ``qd``.

The test (per joint): the free motion of the first :attr:`WatchConfig.baseline_s` (50 s)
after :attr:`WatchConfig.warmup_s` is the session's *baseline* (frozen then); the last
:attr:`WatchConfig.window_s` (30 s) are the *current window*. The two are compared only where
their states overlap (matched support): a window's row is *covered* when at least
:attr:`WatchConfig.match_min` (5) baseline rows are its neighbours (every angle within
:attr:`WatchConfig.match_radius_rad`, 0.2 rad, and joint ``j`` moving in the same direction);
a row in a pose the baseline never visited is not compared at all, so the model's steady,
pose-dependent misfit cannot pass for a change when the operator wanders elsewhere. For each
covered row the watch takes the difference ``e`` between its ``tau_ext_j`` and its
neighbours' mean, and regresses::

    e = (x - x_nbr) a  +  G_v g

``x - x_nbr`` (the row's angles, joint velocity and acceleration less its neighbours' mean: the
local slope of the steady misfit) is fitted, never tested; ``G_v`` is the form of a change in
variable ``v``: ``t`` (a level change since the baseline, and a trend: 1, sgn qd_j, t, t sgn
qd_j), ``q<k>`` and ``q2-q3`` (five hat functions of the angle, alone and times sgn qd_j),
``tau<j>`` (1, sgn qd_j, tau_j, |tau_j| sgn qd_j, with the low-passed motor torque); ``level``
is (1, sgn qd_j) alone. The regression also holds the baseline matched with itself: each
baseline row less the mean of its baseline neighbours at least
:attr:`WatchConfig.correlation_s` away in time (other moves, never its own correlated noise),
with ``G_v = 0``. Those rows are what a comparison gives without a change: they fit the slope
``a`` together with the window's rows, so a window holding two or three moves cannot pass a
change off as a slope (fitted on the window alone, ``a`` took most of a friction change seen in
one or two moves), and they give the noise and its autocorrelation their degrees of freedom.
The F-test of ``g = 0`` allows for the residual's autocorrelation (F and the residual degrees
of freedom divided by the Bartlett-weighted variance inflation ``1 + 2 sum_l (1 - l / (L + 1))
rho_l``, lags up to :attr:`WatchConfig.correlation_s`, 1 s: about one free move, over which the
misfit is correlated) and is Bonferroni-corrected over the candidates. A joint *fires* at one
evaluation when the best candidate's corrected p-value is below :attr:`WatchConfig.alpha`
(1e-8) and the size of the change it explains (RMS over the window's covered rows of what it
adds to the fit, less what noise alone would add) is at least
:attr:`WatchConfig.min_effect_fraction` (7 %) of the joint's RMS torque where it is measured:
the low-passed motor torque over the joint's rows since the warm-up (free motion, the joint
moving). Not over the whole session: contact multiplies a joint's torque (the Omni's second
joint: 0.15 N m RMS with the palpation's contact, 0.03 N m in its free motion), and a change is
judged against the torque the joint carries in the motion the watch sees. The threshold is 7 %:
with the baseline's own rows in the test, clean simulated sessions
(benchmarks/watch_offline.py, seeds 1-6) show window-versus-baseline differences of up to 6 %
of a joint's RMS torque at p far below alpha and up to 8 % at p just above it (poses and
motions the matching pairs imperfectly), and at 5 % one of them was reported; the planted 10 %
effects are first reported at 8-51 %. The variable named is the candidate that improves most
significantly on a level change alone (nested F-test, p below :attr:`WatchConfig.alpha_name`),
else ``t`` (the torque changed since the baseline). A dependence is reported once a joint fires
in :attr:`WatchConfig.persistence` (4) consecutive evaluations; it then stays reported
(``finding``, with ``holds`` telling whether the latest evaluation still fired) until
:meth:`ResidualWatch.reset` (a model is loaded). Because it compares the session with its own
beginning, the watch sees what changes during a session, in the poses of the baseline; an
effect present from the first sample is the job of ``teleop-force residual RECORDING --model
MODEL`` (the command the diagnostics name).

Cost: one evaluation decodes about a second of payloads, estimates them (1.5 s of samples
with the context), and solves, per joint, about ten
least-squares problems of (baseline's matched rows + window's) rows, a few hundred each, and at
most 15 columns, plus one (window rows x baseline rows) neighbour search; the baseline is
matched with itself once per joint, when it is frozen: milliseconds per second of stream
(``benchmarks/watch_offline.py`` prints the time per call).

Published: :class:`~teleop_force.transport.messages.ServiceDiagnostics` (JSON) on
``omni/<device>/service/diagnostics`` after every evaluation.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy import special as scipy_special

from teleop_force.errors import ConfigurationError, MessageError
from teleop_force.service.watch_residual import WatchResidual
from teleop_force.transport import messages as m

#: Samples the ring keeps (65.5 s at 1 kHz): more than a window plus the decoding margin.
DEFAULT_RING_CAPACITY: Final = 1 << 16
#: The command the diagnostics name, filled with the recording and the model when known.
COMMAND_TEMPLATE: Final = "teleop-force residual {recording} --model {model}"
#: Half-span of the central differences of ``q`` for the velocity [samples at 1 kHz].
_VELOCITY_HALF_SPAN_S: Final = 0.010
#: Half-span of the second difference for the acceleration [s].
_ACCELERATION_HALF_SPAN_S: Final = 0.025
#: Width of the smoothed sign of the velocity [rad/s].
_SIGN_WIDTH_RAD_S: Final = 0.05
#: Hat functions per angle of the position candidates.
_HATS: Final = 5
#: Above this gap or below zero between stamps, the stream restarted [s].
_RESTART_GAP_S: Final = 0.5
_EPS: Final = 1e-300
#: Run ids of the baseline's own rows are shifted by this (no lag pair across the two parts).
_RUN_OFFSET: Final = 1 << 40


@dataclass(frozen=True)
class WatchConfig:
    """Settings of :class:`ResidualWatch` (the module docstring says what each one does).

    Attributes:
        period_s: Time between two evaluations (the thread's period).
        window_s: Length of the current window (stream time).
        warmup_s: Stream time ignored at the start (filters settling, the arm starting).
        baseline_s: Stream time after :attr:`warmup_s` that makes the baseline.
        decimate_hz: Rate the rows of the regression are taken at.
        free_force_n: Estimated tip force below which a sample may be free motion.
        guard_s: Samples this close to one above :attr:`free_force_n` are not free.
        min_speed_rad_s: A joint's rows need it to move faster than this.
        settle_s: Samples this close after a stream (re)start are left out.
        alpha: Corrected p-value below which a joint fires (with the effect size).
        alpha_name: Nested p-value below which a specific variable is named (else ``t``).
        min_effect_fraction: Smallest change reported, in units of the joint's RMS torque
            over its free rows (where the change is measured).
        persistence: Consecutive firing evaluations before a dependence is reported.
        min_rows: Fewest covered rows of a joint in the current window for a test.
        match_radius_rad: A baseline row is a neighbour of a window's row when every angle
            is within this of the row's (and the joint moves in the same direction).
        match_min: Fewest neighbours for a window's row to be covered (compared).
        correlation_s: Longest lag of the residual's autocorrelation the test allows for.
        ring_capacity: Samples the ring keeps (a power of two).

    """

    period_s: float = 1.0
    window_s: float = 30.0
    warmup_s: float = 5.0
    baseline_s: float = 50.0
    decimate_hz: float = 50.0
    free_force_n: float = 0.5
    guard_s: float = 0.15
    min_speed_rad_s: float = 0.08
    settle_s: float = 1.0
    alpha: float = 1e-8
    alpha_name: float = 1e-4
    min_effect_fraction: float = 0.07
    persistence: int = 4
    min_rows: int = 40
    match_radius_rad: float = 0.2
    match_min: int = 5
    correlation_s: float = 1.0
    ring_capacity: int = DEFAULT_RING_CAPACITY

    def __post_init__(self) -> None:
        """Check every value's range; raise ConfigurationError."""
        positive = (
            "period_s", "window_s", "baseline_s", "decimate_hz", "free_force_n",
            "alpha", "alpha_name", "min_effect_fraction", "match_radius_rad",
        )  # fmt: skip
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ConfigurationError(f"{name} must be a finite number > 0, got {value!r}")
        for name in ("warmup_s", "guard_s", "min_speed_rad_s", "settle_s", "correlation_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ConfigurationError(f"{name} must be a finite number >= 0, got {value!r}")
        if not (self.alpha < 1.0 and self.alpha_name < 1.0):
            raise ConfigurationError("alpha and alpha_name must be < 1")
        if not (isinstance(self.persistence, int) and self.persistence >= 1):
            raise ConfigurationError(f"persistence must be an integer >= 1, got {self.persistence}")
        if not (isinstance(self.min_rows, int) and self.min_rows >= 20):
            raise ConfigurationError(f"min_rows must be an integer >= 20, got {self.min_rows}")
        if not (isinstance(self.match_min, int) and self.match_min >= 1):
            raise ConfigurationError(f"match_min must be an integer >= 1, got {self.match_min}")
        capacity = self.ring_capacity
        if not (isinstance(capacity, int) and capacity >= 1024 and capacity & (capacity - 1) == 0):
            raise ConfigurationError(f"ring_capacity must be a power of two >= 1024: {capacity}")


class PayloadRing:
    """Preallocated ring of (joint state, estimate) payload pairs, one writer, one reader.

    :meth:`append` is the only call on the 1 kHz path: two stores of references into
    preallocated lists and one counter increment (atomic under the GIL). The reader copies a
    range of slots and checks, afterwards, that the writer has not lapped it.
    """

    __slots__ = ("_estimates", "_joint_states", "_mask", "capacity", "count")

    def __init__(self, capacity: int = DEFAULT_RING_CAPACITY) -> None:
        """Allocate ``capacity`` slots (a power of two)."""
        if capacity < 1 or capacity & (capacity - 1):
            raise ConfigurationError(f"capacity must be a power of two, got {capacity}")
        self.capacity = capacity
        self._mask = capacity - 1
        self._joint_states: list[bytes] = [b""] * capacity
        self._estimates: list[bytes] = [b""] * capacity
        #: Samples appended since the start (never reset: the reader keeps its own position).
        self.count = 0

    def append(self, joint_state: bytes, estimate: bytes) -> None:
        """Keep one sample: the joint-state payload and the estimate computed from it."""
        i = self.count & self._mask
        self._joint_states[i] = joint_state
        self._estimates[i] = estimate
        self.count += 1

    def read(self, start: int, stop: int) -> tuple[list[bytes], list[bytes]] | None:
        """Copy samples ``start .. stop - 1`` (absolute counts); ``None`` if overwritten."""
        if stop <= start:
            return [], []
        if self.count - start > self.capacity:
            return None
        mask = self._mask
        a, b = start & mask, ((stop - 1) & mask) + 1
        if a < b:
            js, est = self._joint_states[a:b], self._estimates[a:b]
        else:
            js = self._joint_states[a:] + self._joint_states[:b]
            est = self._estimates[a:] + self._estimates[:b]
        if self.count - start > self.capacity:  # lapped while copying
            return None
        return js, est


def _joint_state_dtype(n: int) -> np.dtype:
    return np.dtype(
        {
            "names": ["seq", "t_ns", "q", "effort"],
            "formats": ["<u4", "<i8", ("<f8", (n,)), ("<f8", (n,))],
            "offsets": [4, 8, 17, 17 + 16 * n],
            "itemsize": 17 + 24 * n,
        }
    )


def _estimate_dtype(n: int) -> np.dtype:
    return np.dtype(
        {
            "names": ["f", "tau_ext", "tau_motor"],
            "formats": [("<f8", (3,)), ("<f8", (n,)), ("<f8", (n,))],
            "offsets": [21, 45, 45 + 16 * n],
            "itemsize": 45 + 32 * n + (n + 7) // 8,
        }
    )


@dataclass(frozen=True, eq=False)
class Samples:
    """Decoded samples at the full rate (arrays of one stretch of the ring).

    Attributes:
        index: Absolute sample count of each row (N,).
        t_s: Stream time of the watch [s] (N,).
        seq: Joint-state sequence numbers (N,).
        q_rad: Joint angles (N, n).
        effort_nm: Motor torques of the joint states (N, n).
        force_n: Estimated tip force (N, 3), NaN when singular.
        tau_ext_nm: Estimated external torques (N, n).
        tau_motor_nm: Low-passed motor torques of the estimate (N, n).

    """

    index: np.ndarray
    t_s: np.ndarray
    seq: np.ndarray
    q_rad: np.ndarray
    effort_nm: np.ndarray
    force_n: np.ndarray
    tau_ext_nm: np.ndarray
    tau_motor_nm: np.ndarray


def decode_samples(
    joint_states: Sequence[bytes], estimates: Sequence[bytes], n: int, first_index: int, t0_ns: int
) -> Samples:
    """Decode payload pairs in bulk; raise MessageError if one is not of the expected size."""
    js_type, est_type = _joint_state_dtype(n), _estimate_dtype(n)
    js_raw, est_raw = b"".join(joint_states), b"".join(estimates)
    count = len(joint_states)
    if len(js_raw) != count * js_type.itemsize or len(est_raw) != count * est_type.itemsize:
        raise MessageError(f"residual watch: payloads are not all of {n} joints")
    js = np.frombuffer(js_raw, dtype=js_type)
    est = np.frombuffer(est_raw, dtype=est_type)
    return Samples(
        index=first_index + np.arange(count),
        t_s=(js["t_ns"] - t0_ns) * 1e-9,
        seq=js["seq"].astype(np.int64),
        q_rad=np.array(js["q"], dtype=float).reshape(count, n),
        effort_nm=np.array(js["effort"], dtype=float).reshape(count, n),
        force_n=np.array(est["f"], dtype=float).reshape(count, 3),
        tau_ext_nm=np.array(est["tau_ext"], dtype=float).reshape(count, n),
        tau_motor_nm=np.array(est["tau_motor"], dtype=float).reshape(count, n),
    )


@dataclass(frozen=True, eq=False)
class Rows:
    """Decimated regression rows (arrays of M rows).

    Attributes:
        t_s: Stream time [s]; ``run``: id of the contiguous run a row belongs to;
        q_rad, qd_rad_s, qdd_rad_s2: angles and their central differences;
        tau_motor_nm, tau_ext_nm: the estimate's low-passed motor and external torques;
        free: (M, n) whether the row is free motion with joint ``j`` moving.

    """

    t_s: np.ndarray
    run: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    qdd_rad_s2: np.ndarray
    tau_motor_nm: np.ndarray
    tau_ext_nm: np.ndarray
    free: np.ndarray

    def take(self, keep: np.ndarray) -> Rows:
        """Return the rows where ``keep`` is true."""
        return Rows(*(getattr(self, f)[keep] for f in _ROW_FIELDS))

    @staticmethod
    def concat(parts: Sequence[Rows]) -> Rows:
        """Rows of ``parts`` one after the other."""
        return Rows(*(np.concatenate([getattr(p, f) for p in parts]) for f in _ROW_FIELDS))


_ROW_FIELDS: Final = (
    "t_s", "run", "q_rad", "qd_rad_s", "qdd_rad_s2", "tau_motor_nm", "tau_ext_nm", "free",
)  # fmt: skip


def _block_mean(x: np.ndarray, idx: np.ndarray, step: int) -> np.ndarray:
    """Mean of ``x`` over the ``step`` samples centred on each of ``idx`` (anti-aliasing)."""
    before = step // 2
    c = np.concatenate((np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)))
    return (c[idx + (step - before)] - c[idx - before]) / step


def _dilate(mask: np.ndarray, half: int) -> np.ndarray:
    """``mask`` widened by ``half`` samples on both sides (a running maximum)."""
    if half <= 0 or not mask.any():
        return mask.copy()
    c = np.concatenate(([0], np.cumsum(mask, dtype=np.int64)))
    n = mask.size
    idx = np.arange(n)
    hi = np.minimum(idx + half + 1, n)
    lo = np.maximum(idx - half, 0)
    return (c[hi] - c[lo]) > 0


@dataclass(frozen=True)
class Check:
    """The test of one joint at one evaluation.

    Attributes:
        joint: Joint index (0-based).
        rows: Rows of the current window tested (those the baseline covers).
        variable: The variable named (``None``: no test, too few covered rows).
        p_value: Bonferroni-corrected p-value of the best candidate (1.0 without a test).
        effect_nm: RMS of what the best candidate explains over the covered rows, less what
            noise alone would [N m].
        effect_fraction: ``effect_nm`` over the joint's RMS torque.
        fired: Whether this evaluation counts toward a report.

    """

    joint: int
    rows: int
    variable: str | None = None
    p_value: float = 1.0
    effect_nm: float = 0.0
    effect_fraction: float = 0.0
    fired: bool = False


@dataclass(frozen=True)
class Finding:
    """A reported, persistent dependence.

    Attributes:
        joint: Joint index (0-based).
        variable: Variable named at the latest firing evaluation.
        effect_fraction: Its effect size (fraction of the joint's RMS torque).
        effect_nm: Its effect size [N m].
        p_value: Its corrected p-value.
        since_s: Stream time of the evaluation that made it persistent [s].
        first_fired_s: Stream time of the first of the consecutive firing evaluations [s].
        holds: Whether the latest evaluation still fired.

    """

    joint: int
    variable: str
    effect_fraction: float
    effect_nm: float
    p_value: float
    since_s: float
    first_fired_s: float
    holds: bool = True


@dataclass
class _Effort:
    """Running sums of each joint's squared low-passed motor torque over its free rows."""

    sum_sq: np.ndarray
    count: np.ndarray

    def rms_nm(self) -> np.ndarray:
        return np.sqrt(self.sum_sq / np.maximum(self.count, 1))


class ResidualWatch:
    """Sliding-window test of the external torque in free motion (module docstring)."""

    def __init__(
        self,
        n_joints: int,
        config: WatchConfig | None = None,
        *,
        device: str = "slave",
        model_path: str | None = None,
        recording_path: Callable[[], str | None] | None = None,
        residual: WatchResidual | None = None,
    ) -> None:
        """Prepare the ring; nothing runs until :meth:`start` (or :meth:`evaluate` by hand).

        ``residual``: the watch's own estimator (:class:`~teleop_force.service.watch_residual.
        WatchResidual` of the model running), which makes the force, ``tau_ext`` and motor
        torque tested from the joint states; ``None``: the published estimates are tested.
        """
        if not 1 <= n_joints <= m.MAX_JOINTS:
            raise ConfigurationError(f"n_joints must be in 1..{m.MAX_JOINTS}, got {n_joints}")
        self.n = n_joints
        self.config = config if config is not None else WatchConfig()
        self.device = device
        self.model_path = model_path
        self._recording_path = recording_path
        self._residual = residual
        self.ring = PayloadRing(self.config.ring_capacity)
        #: Bound method of the ring: what the receive callback calls.
        self.append = self.ring.append
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._publish: Callable[[bytes], None] | None = None
        self._lock = threading.Lock()  # evaluations and resets
        self.evaluations = 0
        self.errors = 0
        self.last_error = ""
        self.evaluation_ms_max = 0.0
        self._evaluation_ms_sum = 0.0
        self._seq = 0
        self._start_state()

    def _start_state(self) -> None:
        if self._residual is not None:
            self._residual.reset()
        self._read = self.ring.count  # the next sample to decode
        self._t0_ns: int | None = None
        self._last_t_s: float | None = None
        self._last_seq = 0
        self._run = 0
        self._run_start_s = 0.0
        #: samples (with their run ids and run starts) kept as the next decode's context
        self._tail: tuple[Samples, np.ndarray, np.ndarray] | None = None
        self._next_first = 0
        self._kept: list[Rows] = []  # the window's rows, oldest first
        self._baseline_rows: list[Rows] = []
        self._baseline: Rows | None = None
        self._effort = _Effort(np.zeros(self.n), np.zeros(self.n, dtype=np.int64))
        self._baseline_complete = False
        self._consecutive = [0] * self.n
        self._first_fired_s = [math.nan] * self.n
        #: per joint: the baseline matched with itself (computed once it is frozen)
        self._null: dict[int, _Matched | None] = {}
        self.findings: dict[int, Finding] = {}
        self.checks: tuple[Check, ...] = ()
        self.stream_s = 0.0

    # -- lifetime -----------------------------------------------------------------------------

    def start(self, publish: Callable[[bytes], None] | None = None) -> ResidualWatch:
        """Start the evaluation thread; ``publish`` gets each diagnostics payload."""
        self._publish = publish
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="residual-watch", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread (idempotent)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout_s)

    def reset(self, model_path: str | None = None, residual: WatchResidual | None = None) -> None:
        """Forget the baseline and the findings (a new model runs from the next sample).

        ``residual``: the new model's :class:`~teleop_force.service.watch_residual.
        WatchResidual` (``None`` keeps the current one).
        """
        with self._lock:
            if model_path is not None:
                self.model_path = model_path
            if residual is not None:
                self._residual = residual
            self._start_state()

    def _loop(self) -> None:
        period = self.config.period_s
        next_s = time.perf_counter() + period
        while not self._stop.wait(max(0.0, next_s - time.perf_counter())):
            next_s += period
            try:
                payload = self.evaluate_and_encode()
                publish = self._publish
                if publish is not None and payload is not None:
                    publish(payload)
            except Exception as exc:  # the thread must outlive one bad evaluation
                self.errors += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
            if next_s < time.perf_counter():  # fell behind (a stalled machine): skip
                next_s = time.perf_counter() + period

    # -- evaluation ---------------------------------------------------------------------------

    def evaluate_and_encode(self) -> bytes | None:
        """Evaluate once and return the diagnostics payload (``None`` before any sample)."""
        with self._lock:
            self.evaluate()
            if self._t0_ns is None:
                return None
            message = self.diagnostics()
        return message.encode()

    def evaluate(self) -> tuple[Check, ...]:
        """Decode the new samples, update the baseline or the window, test; return the checks."""
        started = time.perf_counter()
        rows = self._ingest()
        if rows is not None:
            self._add_rows(rows)
        checks = self._test()
        self.checks = checks
        self._update_findings(checks)
        elapsed_ms = (time.perf_counter() - started) * 1e3
        self.evaluations += 1
        self._evaluation_ms_sum += elapsed_ms
        self.evaluation_ms_max = max(self.evaluation_ms_max, elapsed_ms)
        return checks

    def _ingest(self) -> Rows | None:
        """Decode the samples appended since the last call; return the new rows."""
        config = self.config
        count = self.ring.count
        start = max(self._read, count - self.ring.capacity + 1024)
        if count - start < 1:
            return None
        copied = self.ring.read(start, count)
        if copied is None:
            return None
        if start > self._read:  # lapped: the context is lost
            self._tail, self._next_first = None, 0
            if self._residual is not None:
                self._residual.reset()
        if self._t0_ns is None:
            self._t0_ns = m.peek_header(copied[0][0])[3]
        fresh = decode_samples(copied[0], copied[1], self.n, start, self._t0_ns)
        self._read = count
        run, run_start = self._runs(fresh)
        if self._residual is not None:
            own = self._residual(fresh.t_s, fresh.q_rad, fresh.effort_nm, run, run_start)
            fresh = dataclasses.replace(
                fresh, force_n=own.force_tip_in_base_n, tau_ext_nm=own.tau_external_nm,
                tau_motor_nm=own.tau_motor_filtered_nm,
            )  # fmt: skip
        s = fresh
        if self._tail is not None:
            tail, tail_run, tail_start = self._tail
            s = _concat_samples(tail, fresh)
            run = np.concatenate((tail_run, run))
            run_start = np.concatenate((tail_start, run_start))
        # a row needs context on both sides (guard, differences): the samples after the
        # last row are decoded again next time, with `margin` samples before them
        margin = round((config.guard_s + _ACCELERATION_HALF_SPAN_S + 0.01) * 1000.0) + 1
        step = max(1, round(1000.0 / config.decimate_hz))
        total = s.index.size
        first = self._next_first
        end = max(total - margin, first)
        keep_from = max(end - margin, 0)
        self._tail = (_cut_samples(s, keep_from), run[keep_from:], run_start[keep_from:])
        self._next_first = end - keep_from
        self.stream_s = float(s.t_s[-1])
        if end <= first:
            return None
        return self._rows(s, run, run_start, first, end, step)

    def _runs(self, s: Samples) -> tuple[np.ndarray, np.ndarray]:
        """Run id and run start time of each new sample (a run ends at a stream restart)."""
        t, seq = s.t_s, s.seq
        jump = np.zeros(t.size, dtype=bool)
        if t.size > 1:
            dts = np.diff(t)
            jump[1:] = (dts <= 0.0) | (dts > _RESTART_GAP_S) | (np.diff(seq) != 1)
        if self._last_t_s is not None:
            dt0 = t[0] - self._last_t_s
            jump[0] = dt0 <= 0.0 or dt0 > _RESTART_GAP_S or int(seq[0]) - self._last_seq != 1
        run = self._run + np.cumsum(jump)
        starts = np.where(jump, t, np.nan)
        if not jump[0]:
            starts[0] = self._run_start_s if self._last_t_s is not None else t[0]
        filled = np.where(np.isfinite(starts), np.arange(t.size), 0)
        np.maximum.accumulate(filled, out=filled)
        run_start = starts[filled]
        self._run, self._run_start_s = int(run[-1]), float(run_start[-1])
        self._last_t_s, self._last_seq = float(t[-1]), int(seq[-1])
        return run, run_start

    def _rows(
        self, s: Samples, run: np.ndarray, run_start: np.ndarray, first: int, stop: int, step: int
    ) -> Rows | None:
        """Rows at the decimated samples (absolute count % step == 0) in ``[first, stop)``."""
        config = self.config
        t = s.t_s
        # contact (or no force: singular) anywhere near a sample: not free
        force = np.linalg.norm(s.force_n, axis=1)
        contact = ~(force < config.free_force_n)  # NaN counts as contact
        not_free = _dilate(contact, round(config.guard_s * 1000.0))
        hv = max(1, round(_VELOCITY_HALF_SPAN_S * 1000.0))
        ha = max(1, round(_ACCELERATION_HALF_SPAN_S * 1000.0))
        idx = np.arange(first, stop)
        idx = idx[(s.index[idx] % step) == 0]
        idx = idx[(idx - ha >= 0) & (idx + ha < t.size)]
        if idx.size == 0:
            return None
        q = s.q_rad
        qd = (q[idx + hv] - q[idx - hv]) / (t[idx + hv] - t[idx - hv])[:, None]
        h = (t[idx + ha] - t[idx - ha])[:, None] * 0.5
        qdd = (q[idx + ha] - 2.0 * q[idx] + q[idx - ha]) / (h * h)
        usable = (run[idx - ha] == run[idx + ha]) & ~not_free[idx]
        usable &= (t[idx] - run_start[idx] >= config.settle_s) & (t[idx] >= config.warmup_s)
        free = usable[:, None] & (np.abs(qd) > config.min_speed_rad_s)
        return Rows(
            t_s=t[idx],
            run=run[idx],
            q_rad=q[idx],
            qd_rad_s=qd,
            qdd_rad_s2=qdd,
            tau_motor_nm=s.tau_motor_nm[idx],
            tau_ext_nm=_block_mean(s.tau_ext_nm, idx, step),
            free=free,
        )

    def _add_rows(self, rows: Rows) -> None:
        config = self.config
        # each joint's RMS torque over the rows its test uses (free, the joint moving)
        effort = np.where(rows.free, rows.tau_motor_nm, 0.0)
        self._effort.sum_sq += np.sum(effort * effort, axis=0)
        self._effort.count += np.sum(rows.free, axis=0)
        rows = rows.take(np.any(rows.free, axis=1))
        end = config.warmup_s + config.baseline_s
        in_baseline = rows.t_s < end
        if np.any(in_baseline):
            self._baseline_rows.append(rows.take(in_baseline))
        if self.stream_s >= end and not self._baseline_complete:
            self._baseline_complete = True
            self._baseline = Rows.concat(self._baseline_rows) if self._baseline_rows else None
            self._baseline_rows = []
        rows = rows.take(~in_baseline)
        if rows.t_s.size:
            self._kept.append(rows)
        horizon = self.stream_s - config.window_s
        while self._kept and self._kept[0].t_s[-1] < horizon:
            self._kept.pop(0)

    def _split(self) -> tuple[Rows, Rows] | None:
        """Return the baseline rows and the current window's (``None``: no baseline yet)."""
        if self._baseline is None or not self._kept:
            return None
        rows = Rows.concat(self._kept)
        return self._baseline, rows.take(rows.t_s >= self.stream_s - self.config.window_s)

    def _test(self) -> tuple[Check, ...]:
        split = self._split()
        if split is None:
            return ()
        base, current = split
        rms = self._effort.rms_nm()
        return tuple(self._test_joint(j, base, current, float(rms[j])) for j in range(self.n))

    def _test_joint(self, j: int, base: Rows, current: Rows, rms_nm: float) -> Check:
        """Test joint ``j``: the current window against the baseline where their states overlap."""
        config = self.config
        b = base.take(base.free[:, j])
        c = current.take(current.free[:, j])
        matched = _match(b, c, j, config.match_radius_rad, config.match_min)
        if matched is None or matched.rows < config.min_rows:
            return Check(joint=j, rows=0 if matched is None else matched.rows)
        cc = c.take(matched.keep)
        candidates = _candidates(cc, j)
        if j not in self._null:
            self._null[j] = _match(
                b, b, j, config.match_radius_rad, config.match_min, apart_s=config.correlation_s
            )
        null = self._null[j]
        if null is None or null.rows < config.min_rows:
            null = _Matched.empty(matched.nuisance.shape[1])
        # the baseline's own rows (G = 0) stacked before the window's: they share the slope of
        # the steady misfit and the noise; only the window's rows carry the change
        e = np.concatenate((null.difference, matched.difference))
        nuisance = np.vstack((null.nuisance, matched.nuisance))
        run = np.concatenate((null.run - _RUN_OFFSET, matched.run))
        t_s = np.concatenate((null.t_s, cc.t_s))
        step_s = 1.0 / config.decimate_hz
        pairs = _lag_pairs(run, t_s, step_s, round(config.correlation_s / step_s))
        candidates = [(k, np.vstack((np.zeros((null.rows, g.shape[1])), g))) for k, g in candidates]
        restricted = _fit(nuisance, e, pairs)
        best: tuple[float, str, float] | None = None
        fits: dict[str, _Fit] = {}
        for name, columns in candidates:
            full = _fit(np.hstack((nuisance, columns)), e, pairs)
            fits[name] = full
            p = _f_test(restricted, full) * len(candidates)
            if best is None or p < best[0]:
                best = (p, name, _effect_nm(restricted, full, matched.rows))
        assert best is not None
        p_value, _, effect_nm = best
        # the variable named: the candidate that improves most on a level change alone
        specific = [(k, f) for k, f in fits.items() if k != "level"]
        named, named_p = "level", 1.0
        for key, full in specific:
            p = _f_test(fits["level"], full) * len(specific)
            if p < named_p:
                named, named_p = key, p
        variable = _variable_name(named if named_p < config.alpha_name else "level")
        fraction = effect_nm / max(rms_nm, _EPS)
        fired = p_value < config.alpha and fraction >= config.min_effect_fraction
        return Check(
            joint=j,
            rows=matched.rows,
            variable=variable,
            p_value=min(1.0, p_value),
            effect_nm=effect_nm,
            effect_fraction=fraction,
            fired=bool(fired),
        )

    def _update_findings(self, checks: tuple[Check, ...]) -> None:
        persistence = self.config.persistence
        now = self.stream_s
        for check in checks:
            j = check.joint
            if check.fired:
                if self._consecutive[j] == 0:
                    self._first_fired_s[j] = now
                self._consecutive[j] += 1
            else:
                self._consecutive[j] = 0
            finding = self.findings.get(j)
            if check.fired and (finding is not None or self._consecutive[j] >= persistence):
                assert check.variable is not None
                self.findings[j] = Finding(
                    joint=j,
                    variable=check.variable,
                    effect_fraction=check.effect_fraction,
                    effect_nm=check.effect_nm,
                    p_value=check.p_value,
                    since_s=now if finding is None else finding.since_s,
                    first_fired_s=(
                        self._first_fired_s[j] if finding is None else finding.first_fired_s
                    ),
                    holds=True,
                )
            elif finding is not None and finding.holds:
                self.findings[j] = Finding(**{**vars(finding), "holds": False})

    # -- reporting ----------------------------------------------------------------------------

    @property
    def state(self) -> str:
        """``baseline`` (collecting it), ``watching`` or ``dependence`` (a finding)."""
        if self.findings:
            return "dependence"
        return "watching" if self._baseline_complete else "baseline"

    def command(self) -> str:
        """Return the command to run next on a finding (``""`` without one)."""
        if not self.findings:
            return ""
        recording = self._recording_path() if self._recording_path is not None else None
        return COMMAND_TEMPLATE.format(
            recording=recording or "RECORDING", model=self.model_path or "MODEL"
        )

    def diagnostics(self) -> m.ServiceDiagnostics:
        """Return the diagnostics message of the latest evaluation."""
        self._seq = (self._seq + 1) & 0xFFFF_FFFF
        rms = self._effort.rms_nm() if self._effort.count.any() else None
        finding = self._headline()
        return m.ServiceDiagnostics(
            seq=self._seq,
            t_ns=time.time_ns(),
            device=self.device,
            state=self.state,
            stream_s=round(self.stream_s, 3),
            baseline_complete=self._baseline_complete,
            rms_torque_nm=tuple(float(x) for x in rms) if rms is not None else (),
            checks=tuple(
                m.DiagnosticCheck(
                    joint=c.joint + 1,
                    rows=c.rows,
                    variable=c.variable,
                    p_value=c.p_value,
                    effect_fraction=c.effect_fraction,
                    consecutive=self._consecutive[c.joint],
                )
                for c in self.checks
            ),
            finding=(
                None
                if finding is None
                else m.DiagnosticFinding(
                    joint=finding.joint + 1,
                    variable=finding.variable,
                    effect_fraction=finding.effect_fraction,
                    effect_nm=finding.effect_nm,
                    p_value=finding.p_value,
                    since_s=finding.since_s,
                    holds=finding.holds,
                )
            ),
            command=self.command(),
        )

    def _headline(self) -> Finding | None:
        """Return the finding shown first: one that still holds, the largest effect."""
        if not self.findings:
            return None
        return max(self.findings.values(), key=lambda f: (f.holds, f.effect_fraction))

    def stats(self) -> dict[str, object]:
        """JSON statistics (the service's ``residual_watch``)."""
        evaluations = self.evaluations
        return {
            "state": self.state,
            "samples": self.ring.count,
            "evaluations": evaluations,
            "evaluation_ms_mean": (
                round(self._evaluation_ms_sum / evaluations, 3) if evaluations else None
            ),
            "evaluation_ms_max": round(self.evaluation_ms_max, 3),
            "errors": self.errors,
            "last_error": self.last_error,
            "findings": [
                {
                    "joint": f.joint + 1,
                    "variable": f.variable,
                    "effect_fraction": round(f.effect_fraction, 4),
                    "since_s": round(f.since_s, 3),
                    "holds": f.holds,
                }
                for f in self.findings.values()
            ],
        }


# -- the regression -------------------------------------------------------------------------


@dataclass(frozen=True)
class _Fit:
    coef: np.ndarray
    ssr: float
    rows: int
    columns: int
    inflation: float


def _effect_nm(restricted: _Fit, full: _Fit, rows: int) -> float:
    """RMS over ``rows`` (the window's) of what the extra columns of ``full`` explain.

    Less what noise alone would explain.
    """
    extra = full.columns - restricted.columns
    noise = full.ssr / max(full.rows - full.columns, 1) * full.inflation
    explained = (restricted.ssr - full.ssr - noise * max(extra, 0)) / max(rows, 1)
    return math.sqrt(max(explained, 0.0))


def _lag_pairs(run: np.ndarray, t_s: np.ndarray, step_s: float, lags: int) -> list[np.ndarray]:
    """For each lag ``l`` in 1..``lags``: the rows ``i`` whose row ``i + l`` is ``l`` steps on."""
    tick = np.round(t_s / step_s).astype(np.int64)
    pairs = []
    for lag in range(1, min(lags, tick.size - 1) + 1):
        ok = (run[lag:] == run[:-lag]) & (tick[lag:] - tick[:-lag] == lag)
        pairs.append(np.flatnonzero(ok))
    return pairs


def _fit(x: np.ndarray, y: np.ndarray, pairs: Sequence[np.ndarray]) -> _Fit:
    """Least squares with column scaling; the residual's variance inflation (Bartlett).

    The inflation ``1 + 2 sum_l (1 - l / (L + 1)) rho_l`` over the lags of ``pairs`` (rows that
    are ``l`` decimation steps apart in one run), each ``rho_l`` clipped to [0, 1).
    """
    scale = np.sqrt(np.mean(x * x, axis=0))
    scale[scale < 1e-12] = 1.0
    xs = x / scale
    coef, _, rank, _ = np.linalg.lstsq(xs, y, rcond=1e-10)
    residual = y - xs @ coef
    den = float(np.sum(residual * residual))
    inflation = 1.0
    if den > 0.0:
        weight = len(pairs) + 1
        for lag, i in enumerate(pairs, start=1):
            if i.size:
                num = float(np.dot(residual[i], residual[i + lag]))
                rho = min(max(num / den * (y.size / i.size), 0.0), 0.95)
                inflation += 2.0 * (1.0 - lag / weight) * rho
    return _Fit(
        coef=coef / scale,
        ssr=den,
        rows=y.size,
        columns=int(rank),
        inflation=inflation,
    )


def _f_test(restricted: _Fit, full: _Fit) -> float:
    """p-value of the extra columns of ``full``, with the AR(1) inflation of its residual."""
    extra = full.columns - restricted.columns
    df2 = full.rows - full.columns
    if extra <= 0 or df2 <= 0 or full.ssr <= 0.0:
        return 1.0
    f = ((restricted.ssr - full.ssr) / extra) / (full.ssr / df2)
    c = full.inflation
    # the F distribution's survival function (scipy.stats.f.sf, without importing scipy.stats)
    return float(scipy_special.fdtrc(extra, max(df2 / c, 1.0), max(f, 0.0) / c))


def _sign(v: np.ndarray) -> np.ndarray:
    return np.tanh(v / _SIGN_WIDTH_RAD_S)


@dataclass(frozen=True, eq=False)
class _Matched:
    """The current window's rows that the baseline covers, as differences from it.

    Attributes:
        keep: (C,) which of the window's rows are covered.
        difference: ``tau_ext`` of each covered row less the mean of its baseline neighbours.
        nuisance: the row's state less its neighbours' mean (angles, velocity, acceleration
            of the joint): the local slope of the steady misfit, fitted, never tested.
        run: run ids of the covered rows (for the autocorrelation).
        t_s: stream times of the covered rows (for the autocorrelation).

    """

    keep: np.ndarray
    difference: np.ndarray
    nuisance: np.ndarray
    run: np.ndarray
    t_s: np.ndarray

    @property
    def rows(self) -> int:
        return int(self.difference.size)

    @staticmethod
    def empty(columns: int, keep: np.ndarray | None = None) -> _Matched:
        """No row covered (``keep``: all false) or none at all."""
        nothing = np.zeros(0)
        return _Matched(
            np.zeros(0, dtype=bool) if keep is None else keep, nothing,
            np.zeros((0, columns)), np.zeros(0, dtype=np.int64), nothing,
        )  # fmt: skip


def _match(
    base: Rows, current: Rows, j: int, radius_rad: float, least: int, apart_s: float = 0.0
) -> _Matched | None:
    """Pair each current row of joint ``j`` with the baseline rows near its state.

    Neighbours: baseline rows whose every angle is within ``radius_rad`` of the row's and whose
    joint ``j`` moves in the same direction (and, with ``apart_s``, at least that far away in
    time: the baseline matched with itself); a row with fewer than ``least`` is not covered
    (its state was not seen in the baseline: no comparison there).
    """
    if base.t_s.size < least or current.t_s.size == 0:
        return None
    qb, qc = base.q_rad, current.q_rad
    near = np.ones((qc.shape[0], qb.shape[0]), dtype=bool)
    for k in range(qb.shape[1]):
        near &= np.abs(qc[:, k, None] - qb[None, :, k]) <= radius_rad
    near &= (current.qd_rad_s[:, j, None] > 0.0) == (base.qd_rad_s[None, :, j] > 0.0)
    if apart_s > 0.0:
        near &= np.abs(current.t_s[:, None] - base.t_s[None, :]) >= apart_s
    count = near.sum(axis=1)
    keep = count >= least
    if not keep.any():
        return _Matched.empty(0, keep)
    weights = near[keep] / count[keep, None]
    state_b = np.column_stack((qb, base.qd_rad_s[:, j], base.qdd_rad_s2[:, j]))
    state_c = np.column_stack((qc, current.qd_rad_s[:, j], current.qdd_rad_s2[:, j]))[keep]
    return _Matched(
        keep=keep,
        difference=current.tau_ext_nm[keep, j] - weights @ base.tau_ext_nm[:, j],
        nuisance=state_c - weights @ state_b,
        run=current.run[keep],
        t_s=current.t_s[keep],
    )


def _hats(x: np.ndarray, count: int) -> np.ndarray:
    """Piecewise-linear hat functions over the 1-99 % range of ``x`` (they sum to 1)."""
    lo, hi = np.percentile(x, [1.0, 99.0])
    if not hi > lo:
        return np.ones((x.size, 1))
    knots = np.linspace(lo, hi, count)
    width = knots[1] - knots[0]
    xc = np.clip(x, lo, hi)
    return np.maximum(0.0, 1.0 - np.abs(xc[:, None] - knots[None, :]) / width)


def _candidates(rows: Rows, j: int) -> list[tuple[str, np.ndarray]]:
    """``G_v`` of every candidate variable for joint ``j`` on the window's covered rows."""
    s = _sign(rows.qd_rad_s[:, j])
    one = np.ones(s.size)
    dt = rows.t_s - rows.t_s[0]
    out = [("level", np.column_stack((one, s))), ("t", np.column_stack((one, s, dt, dt * s)))]
    tau = rows.tau_motor_nm[:, j]
    out.append((f"tau{j + 1}", np.column_stack((one, s, tau, np.abs(tau) * s))))
    n = rows.q_rad.shape[1]
    angles = [(f"q{k + 1}", rows.q_rad[:, k]) for k in range(n)]
    if n >= 3:
        angles.append(("q2-q3", rows.q_rad[:, 1] - rows.q_rad[:, 2]))
    for name, x in angles:
        h = _hats(x, _HATS)
        out.append((name, np.hstack((h, s[:, None] * h))))
    return out


def _variable_name(candidate: str) -> str:
    return "t" if candidate in ("level", "t") else candidate


def _concat_samples(a: Samples, b: Samples) -> Samples:
    return Samples(
        *(np.concatenate((getattr(a, f), getattr(b, f))) for f in Samples.__dataclass_fields__)
    )


def _cut_samples(s: Samples, start: int) -> Samples:
    return Samples(*(getattr(s, f)[start:] for f in Samples.__dataclass_fields__))


def append_cost_ns(samples: int = 200_000, n_joints: int = 3) -> float:
    """Mean cost of :meth:`ResidualWatch.append` per sample [ns], fresh payloads each call.

    The payloads are made outside the timed loop (the service has them anyway); the cost of
    an empty loop over the same pairs is subtracted.
    """
    watch = ResidualWatch(n_joints)
    js = [m.pack_joint_state(k, k, [0.0] * n_joints, [0.0] * n_joints, [0.0] * n_joints)
          for k in range(samples)]  # fmt: skip
    est = [bytes(45 + 32 * n_joints + (n_joints + 7) // 8) for _ in range(samples)]
    pairs = list(zip(js, est, strict=True))
    del js, est
    append = watch.append
    started = time.perf_counter_ns()
    for a, b in pairs:
        append(a, b)
    elapsed = time.perf_counter_ns() - started
    started = time.perf_counter_ns()
    for _a, _b in pairs:
        pass
    empty = time.perf_counter_ns() - started
    with contextlib.suppress(Exception):
        del pairs
    return (elapsed - empty) / samples
