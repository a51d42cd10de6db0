"""The live residual watch: does the external torque in free motion start to depend on a variable.

With a model that fits, the estimated external torque ``tau_ext`` is noise plus the model's
own, steady misfit whenever the tip touches nothing. When the arm changes during a session (a
payload, a worn cable, warmer motors: something the model does not have), ``tau_ext`` in free
motion acquires a dependence on a variable. The watch tests for that, per joint, on what a real
slave publishes and the service computes (never on a simulator's truth): the joint angles
``q`` (JointState), the estimate's force ``F``, ``tau_ext`` and low-passed motor torque
(ForceEstimate), and time.

Hot path: the service's receive callback only calls :meth:`ResidualWatch.append` with the two
payloads it already has (the joint state received, the estimate published): two reference
stores into preallocated slots of a ring (:class:`PayloadRing`; bytes objects are not tracked
by the garbage collector). Everything else runs in the watch's own thread every
:attr:`WatchConfig.period_s` (1 s), which decodes the new payloads in bulk with NumPy.

Free motion (from published data only): a sample is *free* when the estimated tip force is
finite and below :attr:`WatchConfig.free_force_n` (0.5 N), and no sample within
:attr:`WatchConfig.guard_s` (0.3 s) on either side is above it or singular (contact and its
transients are left out); joint ``j``'s regression uses the free samples at which joint ``j``
moves faster than :attr:`WatchConfig.min_speed_rad_s` (0.08 rad/s: its friction's sign is
defined, away from the pre-sliding regime no model here describes), and none within
:attr:`WatchConfig.settle_s` of a stream (re)start. Velocities and accelerations are central
differences of ``q`` (over 20 and 50 ms): the watch uses the angles, not the published ``qd``.

The test (a Chow test per joint and candidate variable): the free motion of the first
:attr:`WatchConfig.baseline_s` seconds after :attr:`WatchConfig.warmup_s` is the session's
*baseline* (frozen then); the last :attr:`WatchConfig.window_s` seconds are the *current
window*. Both, decimated to :attr:`WatchConfig.decimate_hz`, are regressed together::

    tau_ext_j = phi(x) b  +  D * G_v(x) g          (D = 1 in the current window, 0 in the baseline)

``phi`` is shared (the model's steady misfit: 1, the accelerations, sgn qd_k, qd_k, qd_k qd_l,
a cubic polynomial of the angles, sgn qd_j times each angle; never the motor torque, of which
``tau_ext`` is a part), ``G_v`` the form of a change in variable ``v``: ``t`` (a level change
since the baseline, and a trend in time: D, D sgn qd_j, D t, D t sgn qd_j), ``q<k>`` and
``q2-q3`` (five hat functions of the angle, alone and times sgn qd_j), ``tau<j>`` (D,
D sgn qd_j, D tau_j, D |tau_j| sgn qd_j, with the low-passed motor torque). The F-test of
``g = 0`` is corrected for the residuals' lag-1 autocorrelation ``rho`` (F and the residual
degrees of freedom divided by ``(1 + rho) / (1 - rho)``) and Bonferroni-corrected over the
candidates. A joint *fires* at one evaluation when the best candidate's corrected p-value is
below :attr:`WatchConfig.alpha` (1e-8) and the size of the change it fits (RMS of ``G_v g``
over the current window) is at least :attr:`WatchConfig.min_effect_fraction` (5 %) of the
joint's RMS motor torque (low-passed, every sample after the warm-up, contact included). The
variable named is the candidate that improves most significantly on a level change alone
(nested F-test, p below :attr:`WatchConfig.alpha_name`), else ``t`` (the torque changed since
the baseline). A dependence is reported once a joint fires in :attr:`WatchConfig.persistence`
(4) consecutive evaluations; it then stays reported (``finding``, with ``holds`` telling
whether the latest evaluation still fired) until :meth:`ResidualWatch.reset` (a model is
loaded). Because it compares the session with its own beginning, the watch sees what changes
during a session; an effect present from the first sample is the job of
``teleop-force residual RECORDING --model MODEL`` (the command the diagnostics name).

Published: :class:`~teleop_force.transport.messages.ServiceDiagnostics` (JSON) on
``omni/<device>/service/diagnostics`` after every evaluation.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy import stats as scipy_stats

from teleop_force.errors import ConfigurationError, MessageError
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
        min_effect_fraction: Smallest change reported, in units of the joint's RMS torque.
        persistence: Consecutive firing evaluations before a dependence is reported.
        min_rows: Fewest rows of a joint in the current window for a test.
        ring_capacity: Samples the ring keeps (a power of two).

    """

    period_s: float = 1.0
    window_s: float = 20.0
    warmup_s: float = 5.0
    baseline_s: float = 50.0
    decimate_hz: float = 50.0
    free_force_n: float = 0.5
    guard_s: float = 0.3
    min_speed_rad_s: float = 0.08
    settle_s: float = 1.0
    alpha: float = 1e-8
    alpha_name: float = 1e-4
    min_effect_fraction: float = 0.05
    persistence: int = 4
    min_rows: int = 60
    ring_capacity: int = DEFAULT_RING_CAPACITY

    def __post_init__(self) -> None:
        """Check every value's range; raise ConfigurationError."""
        positive = (
            "period_s", "window_s", "baseline_s", "decimate_hz", "free_force_n",
            "alpha", "alpha_name", "min_effect_fraction",
        )  # fmt: skip
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ConfigurationError(f"{name} must be a finite number > 0, got {value!r}")
        for name in ("warmup_s", "guard_s", "min_speed_rad_s", "settle_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ConfigurationError(f"{name} must be a finite number >= 0, got {value!r}")
        if not (self.alpha < 1.0 and self.alpha_name < 1.0):
            raise ConfigurationError("alpha and alpha_name must be < 1")
        if not (isinstance(self.persistence, int) and self.persistence >= 1):
            raise ConfigurationError(f"persistence must be an integer >= 1, got {self.persistence}")
        if not (isinstance(self.min_rows, int) and self.min_rows >= 20):
            raise ConfigurationError(f"min_rows must be an integer >= 20, got {self.min_rows}")
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
            "names": ["seq", "t_ns", "q"],
            "formats": ["<u4", "<i8", ("<f8", (n,))],
            "offsets": [4, 8, 17],
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
        force_n: Estimated tip force (N, 3), NaN when singular.
        tau_ext_nm: Estimated external torques (N, n).
        tau_motor_nm: Low-passed motor torques of the estimate (N, n).

    """

    index: np.ndarray
    t_s: np.ndarray
    seq: np.ndarray
    q_rad: np.ndarray
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
        rows: Rows of the current window tested.
        variable: The variable named (``None``: no test, too few rows).
        p_value: Bonferroni-corrected p-value of the best candidate (1.0 without a test).
        effect_nm: RMS of the change fitted over the current window [N m].
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
    """Running sum of the squared low-passed motor torque (the joints' RMS torque)."""

    sum_sq: np.ndarray
    count: int = 0

    def rms_nm(self) -> np.ndarray:
        return np.sqrt(self.sum_sq / max(self.count, 1))


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
    ) -> None:
        """Prepare the ring; nothing runs until :meth:`start` (or :meth:`evaluate` by hand)."""
        if not 1 <= n_joints <= m.MAX_JOINTS:
            raise ConfigurationError(f"n_joints must be in 1..{m.MAX_JOINTS}, got {n_joints}")
        self.n = n_joints
        self.config = config if config is not None else WatchConfig()
        self.device = device
        self.model_path = model_path
        self._recording_path = recording_path
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
        self._effort = _Effort(np.zeros(self.n))
        self._baseline_complete = False
        self._consecutive = [0] * self.n
        self._first_fired_s = [math.nan] * self.n
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

    def reset(self, model_path: str | None = None) -> None:
        """Forget the baseline and the findings (a new model runs from the next sample)."""
        with self._lock:
            if model_path is not None:
                self.model_path = model_path
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
        if self._t0_ns is None:
            self._t0_ns = m.peek_header(copied[0][0])[3]
        fresh = decode_samples(copied[0], copied[1], self.n, start, self._t0_ns)
        self._read = count
        run, run_start = self._runs(fresh)
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
            tau_ext_nm=s.tau_ext_nm[idx],
            free=free,
        )

    def _add_rows(self, rows: Rows) -> None:
        config = self.config
        warm = rows.t_s >= config.warmup_s
        effort = rows.tau_motor_nm[warm]
        self._effort.sum_sq += np.sum(effort * effort, axis=0)
        self._effort.count += int(warm.sum())
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
        """Run the Chow test of joint ``j``: baseline vs current window, every candidate."""
        config = self.config
        b = base.take(base.free[:, j])
        c = current.take(current.free[:, j])
        if c.t_s.size < config.min_rows:
            return Check(joint=j, rows=int(c.t_s.size))
        both = Rows.concat((b, c))
        d = np.concatenate((np.zeros(b.t_s.size), np.ones(c.t_s.size)))
        y = both.tau_ext_nm[:, j]
        shared = _shared_design(both, j)
        candidates = _candidates(both, j, d, float(c.t_s[0]))
        restricted = _fit(shared, y, both.run)
        best: tuple[float, str, np.ndarray] | None = None
        fits: dict[str, _Fit] = {}
        for name, columns in candidates:
            full = _fit(np.hstack((shared, columns)), y, both.run)
            fits[name] = full
            p = _f_test(restricted, full) * len(candidates)
            if best is None or p < best[0]:
                change = columns @ full.coef[shared.shape[1] :]
                best = (p, name, change[d == 1.0])
        assert best is not None
        p_value, _, change = best
        effect_nm = float(np.sqrt(np.mean(change * change)))
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
            rows=int(c.t_s.size),
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
        rms = self._effort.rms_nm() if self._effort.count else None
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


def _fit(x: np.ndarray, y: np.ndarray, run: np.ndarray) -> _Fit:
    """Least squares with column scaling; the residual's AR(1) variance inflation."""
    scale = np.sqrt(np.mean(x * x, axis=0))
    scale[scale < 1e-12] = 1.0
    xs = x / scale
    coef, _, rank, _ = np.linalg.lstsq(xs, y, rcond=1e-10)
    residual = y - xs @ coef
    same = run[1:] == run[:-1]
    num = float(np.sum(residual[1:][same] * residual[:-1][same]))
    den = float(np.sum(residual * residual))
    rho = min(max(num / den, 0.0), 0.95) if den > 0.0 else 0.0
    return _Fit(
        coef=coef / scale,
        ssr=den,
        rows=y.size,
        columns=int(rank),
        inflation=(1.0 + rho) / (1.0 - rho),
    )


def _f_test(restricted: _Fit, full: _Fit) -> float:
    """p-value of the extra columns of ``full``, with the AR(1) inflation of its residual."""
    extra = full.columns - restricted.columns
    df2 = full.rows - full.columns
    if extra <= 0 or df2 <= 0 or full.ssr <= 0.0:
        return 1.0
    f = ((restricted.ssr - full.ssr) / extra) / (full.ssr / df2)
    c = full.inflation
    return float(scipy_stats.f.sf(max(f, 0.0) / c, extra, max(df2 / c, 1.0)))


def _sign(v: np.ndarray) -> np.ndarray:
    return np.tanh(v / _SIGN_WIDTH_RAD_S)


def _shared_design(rows: Rows, j: int) -> np.ndarray:
    """``phi``: the steady relation of ``tau_ext_j`` shared by the baseline and the window.

    What the model's own misfit may depend on (never the motor torque, of which ``tau_ext``
    is a part): the velocities, their signs and products, the accelerations, a cubic
    polynomial of the angles and the joint's friction sign times each angle.
    """
    q, qd = rows.q_rad, rows.qd_rad_s
    n = q.shape[1]
    s_j = _sign(qd[:, j])
    cols = [np.ones(q.shape[0])]
    cols += [rows.qdd_rad_s2[:, k] for k in range(n)]
    cols += [_sign(qd[:, k]) for k in range(n)]
    cols += [qd[:, k] for k in range(n)]
    cols += [qd[:, k] * qd[:, i2] for k in range(n) for i2 in range(k, n)]
    qc = q - np.mean(q, axis=0)
    cols += [qc[:, k] for k in range(n)]
    cols += [s_j * qc[:, k] for k in range(n)]
    pairs = [(k, i2) for k in range(n) for i2 in range(k, n)]
    cols += [qc[:, k] * qc[:, i2] for k, i2 in pairs]
    cols += [qc[:, k] * qc[:, i2] * qc[:, i] for k, i2 in pairs for i in range(i2, n)]
    return np.column_stack(cols)


def _hats(x: np.ndarray, count: int) -> np.ndarray:
    """Piecewise-linear hat functions over the 1-99 % range of ``x`` (they sum to 1)."""
    lo, hi = np.percentile(x, [1.0, 99.0])
    if not hi > lo:
        return np.ones((x.size, 1))
    knots = np.linspace(lo, hi, count)
    width = knots[1] - knots[0]
    xc = np.clip(x, lo, hi)
    return np.maximum(0.0, 1.0 - np.abs(xc[:, None] - knots[None, :]) / width)


def _candidates(rows: Rows, j: int, d: np.ndarray, t_start: float) -> list[tuple[str, np.ndarray]]:
    """``D * G_v`` of every candidate variable for joint ``j``."""
    s = _sign(rows.qd_rad_s[:, j])
    dt = np.where(d == 1.0, rows.t_s - t_start, 0.0)
    level = np.column_stack((d, d * s))
    out = [("level", level), ("t", np.column_stack((d, d * s, dt, dt * s)))]
    tau = rows.tau_motor_nm[:, j]
    out.append((f"tau{j + 1}", np.column_stack((d, d * s, d * tau, d * np.abs(tau) * s))))
    n = rows.q_rad.shape[1]
    angles = [(f"q{k + 1}", rows.q_rad[:, k]) for k in range(n)]
    if n >= 3:
        angles.append(("q2-q3", rows.q_rad[:, 1] - rows.q_rad[:, 2]))
    for name, x in angles:
        h = _hats(x, _HATS)
        out.append((name, np.hstack((d[:, None] * h, (d * s)[:, None] * h))))
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
