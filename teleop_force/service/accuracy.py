"""Accuracy of the live force estimate against the plant's true contact force.

The slave publishes its true tip force (ContactForce) with the same ``seq`` as the joint state
of the same tick, and each ForceEstimateMessage carries that joint state's seq as ``source_seq``:
:class:`ForceAccuracy` pairs them exactly, whichever arrives first, and accumulates::

    contact      |F_true| > contact_threshold_n
    rms_error    sqrt(mean |F_est - F_true|^2)      over contact samples
    rms_true     sqrt(mean |F_true|^2)              over the same samples
    relative     rms_error / rms_true

Estimates without a force (NaN: Jacobian near singular) are counted apart, not averaged. The
estimate is a low-passed quantity (the paper's filter, 8 Hz by default), so part of the error
against the raw true force is the filter's lag; :meth:`ForceAccuracy.summary` also reports
the error against the true force passed through the same first-order filter.

Memory and time stay bounded however long the session: the most recent pairs are kept as
they come; once there are ``2 * FOLD_KEEP`` of them, the oldest half (in seq order) is folded
into running sums (and the comparison filter's state), and :meth:`ForceAccuracy.summary`
combines those sums with the recent pairs, so it costs O(FOLD_KEEP), not O(session).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from teleop_force.errors import ConfigurationError

#: Cut-off of the estimator's filters by default
#: (``teleop_force.lowpass.DEFAULT_CUTOFF_HZ``;
#: not imported, to keep scipy out of the supervisor's start-up).
DEFAULT_FILTER_CUTOFF_HZ: Final = 8.0
#: Unpaired messages kept at most (older ones are forgotten).
_MAX_PENDING: Final = 20_000
#: Recent pairs kept as they are (10 s at 1 kHz); older ones are folded into running sums.
FOLD_KEEP: Final = 10_000


class _Folded:
    """Running sums over the pairs already folded, in seq order."""

    def __init__(self) -> None:
        self.paired = 0
        self.contact = 0
        self.sum_error2 = 0.0
        self.sum_true2 = 0.0
        self.sum_lagged2 = 0.0
        self.state: np.ndarray | None = None  # comparison filter state after the last fold


@dataclass(frozen=True)
class AccuracyConfig:
    """Contact threshold and comparison filter of :class:`ForceAccuracy`.

    Attributes:
        contact_threshold_n: A true force above this magnitude is contact [N].
        filter_cutoff_hz: Cut-off of the first-order filter applied to the true force for the
            lag-free comparison (the estimator's cut-off).
        sample_period_s: Nominal sample period of the stream (for that filter).

    """

    contact_threshold_n: float = 0.1
    filter_cutoff_hz: float = DEFAULT_FILTER_CUTOFF_HZ
    sample_period_s: float = 1e-3

    def __post_init__(self) -> None:
        """Check the ranges."""
        for name in ("contact_threshold_n", "filter_cutoff_hz", "sample_period_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigurationError(f"{name} must be > 0, got {value}")


class ForceAccuracy:
    """Pair estimates with true forces by seq and accumulate the errors (thread-safe)."""

    def __init__(self, config: AccuracyConfig | None = None) -> None:
        """Start with no samples."""
        self.config = config if config is not None else AccuracyConfig()
        self._lock = threading.Lock()
        self._true: dict[int, tuple[float, float, float]] = {}
        self._estimated: dict[int, tuple[float, float, float]] = {}
        self._pairs: list[tuple[int, float, float, float, float, float, float]] = []
        self._folded = _Folded()
        self.no_force = 0
        self.latest_true: tuple[float, float, float] | None = None
        self.latest_estimate: tuple[float, float, float] | None = None

    def add_true(self, seq: int, force_n: Sequence[float]) -> None:
        """Add the true force of tick ``seq``."""
        force = (float(force_n[0]), float(force_n[1]), float(force_n[2]))
        with self._lock:
            self.latest_true = force
            estimate = self._estimated.pop(seq, None)
            if estimate is None:
                _bounded_put(self._true, seq, force)
            else:
                self._pair(seq, estimate, force)

    def add_estimate(self, source_seq: int, force_n: Sequence[float]) -> None:
        """Add an estimate computed from the joint state of tick ``source_seq``."""
        force = (float(force_n[0]), float(force_n[1]), float(force_n[2]))
        with self._lock:
            self.latest_estimate = force
            if any(math.isnan(x) for x in force):
                self.no_force += 1
                self._true.pop(source_seq, None)
                return
            true = self._true.pop(source_seq, None)
            if true is None:
                _bounded_put(self._estimated, source_seq, force)
            else:
                self._pair(source_seq, force, true)

    def _pair(
        self, seq: int, estimate: tuple[float, float, float], true: tuple[float, float, float]
    ) -> None:
        self._pairs.append((seq, *estimate, *true))
        if len(self._pairs) >= 2 * FOLD_KEEP:
            self._fold_locked(len(self._pairs) - FOLD_KEEP)

    def _fold_locked(self, count: int) -> None:
        """Fold the ``count`` oldest pairs (by seq) into the running sums."""
        self._pairs.sort(key=lambda pair: pair[0])
        old, self._pairs = self._pairs[:count], self._pairs[count:]
        pairs = np.array(old, dtype=float).reshape(-1, 7)
        sums = _sums(
            pairs[:, 1:4], pairs[:, 4:7], self._filter_gain(), self._folded.state, self.config
        )
        folded = self._folded
        folded.paired += pairs.shape[0]
        folded.contact += sums[0]
        folded.sum_error2 += sums[1]
        folded.sum_true2 += sums[2]
        folded.sum_lagged2 += sums[3]
        folded.state = sums[4]

    def _filter_gain(self) -> float:
        return math.exp(-2.0 * math.pi * self.config.filter_cutoff_hz * self.config.sample_period_s)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(seq, estimate (N, 3), true (N, 3))`` of the recent (not yet folded) pairs, by seq."""
        with self._lock:
            pairs = np.array(self._pairs, dtype=float).reshape(-1, 7)
        order = np.argsort(pairs[:, 0], kind="stable")
        pairs = pairs[order]
        return pairs[:, 0].astype(np.int64), pairs[:, 1:4], pairs[:, 4:7]

    def summary(self) -> dict[str, Any]:
        """Relative RMS error during contact, raw and against the filtered true force."""
        with self._lock:
            pairs = np.array(self._pairs, dtype=float).reshape(-1, 7)
            folded = self._folded
            base = (folded.paired, folded.contact, folded.sum_error2, folded.sum_true2,
                    folded.sum_lagged2, folded.state)  # fmt: skip
        pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
        recent = _sums(pairs[:, 1:4], pairs[:, 4:7], self._filter_gain(), base[5], self.config)
        contact = base[1] + recent[0]
        result: dict[str, Any] = {
            "paired_samples": int(base[0] + pairs.shape[0]),
            "contact_samples": int(contact),
            "contact_threshold_n": self.config.contact_threshold_n,
            "no_force_estimates": self.no_force,
            "rms_error_n": None,
            "rms_true_n": None,
            "relative_rms_error": None,
            "relative_rms_error_vs_filtered_true": None,
        }
        if not contact:
            return result
        rms_true = math.sqrt((base[3] + recent[2]) / contact)
        rms_error = math.sqrt((base[2] + recent[1]) / contact)
        rms_lagged = math.sqrt((base[4] + recent[3]) / contact)
        result.update(
            rms_error_n=round(rms_error, 6),
            rms_true_n=round(rms_true, 6),
            relative_rms_error=round(rms_error / rms_true, 6) if rms_true > 0 else None,
            relative_rms_error_vs_filtered_true=round(rms_lagged / rms_true, 6)
            if rms_true > 0
            else None,
        )
        return result


def _sums(
    estimate: np.ndarray,
    true: np.ndarray,
    a: float,
    state: np.ndarray | None,
    config: AccuracyConfig,
) -> tuple[int, float, float, float, np.ndarray | None]:
    """``(contact count, sum |e|^2, sum |t|^2, sum |e_lagged|^2, filter state)`` over pairs.

    The comparison filter starts at ``state`` (``None``: at the first true force).
    """
    if true.shape[0] == 0:
        return 0, 0.0, 0.0, 0.0, state
    contact = np.linalg.norm(true, axis=1) > config.contact_threshold_n
    filtered = np.empty_like(true)
    current = true[0] if state is None else state
    for k in range(true.shape[0]):
        current = a * current + (1.0 - a) * true[k]
        filtered[k] = current
    return (
        int(contact.sum()),
        float(np.sum((estimate - true)[contact] ** 2)),
        float(np.sum(true[contact] ** 2)),
        float(np.sum((estimate - filtered)[contact] ** 2)),
        current,
    )


def _bounded_put(
    table: dict[int, tuple[float, float, float]], key: int, value: tuple[float, float, float]
) -> None:
    if len(table) >= _MAX_PENDING:
        table.pop(next(iter(table)))
    table[key] = value
