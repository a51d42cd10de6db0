"""Accuracy of the live force estimate against the plant's true contact force.

The slave publishes its true tip force (ContactForce) with the same ``seq`` as the joint state
of the same tick, and each ForceEstimate carries that joint state's seq as ``source_seq``:
:class:`ForceAccuracy` pairs them exactly, whichever arrives first, and accumulates::

    contact      |F_true| > contact_threshold_n
    rms_error    sqrt(mean |F_est - F_true|^2)      over contact samples
    rms_true     sqrt(mean |F_true|^2)              over the same samples
    relative     rms_error / rms_true

Estimates without a force (NaN: Jacobian near singular) are counted apart, not averaged. The
estimate is a low-passed quantity (the paper's filter, 8 Hz by default), so part of the error
against the raw true force is the filter's lag; :meth:`ForceAccuracy.summary` also reports
the error against the true force passed through the same first-order filter.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from teleop_force.errors import ConfigurationError

#: Cut-off of the estimator's filters by default (``teleop_force.lowpass.DEFAULT_CUTOFF_HZ``;
#: not imported, to keep scipy out of the supervisor's start-up).
DEFAULT_FILTER_CUTOFF_HZ: Final = 8.0
#: Unpaired messages kept at most (older ones are forgotten).
_MAX_PENDING: Final = 20_000


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

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(seq, estimate (N, 3), true (N, 3))`` of the paired samples, in seq order."""
        with self._lock:
            pairs = np.array(self._pairs, dtype=float).reshape(-1, 7)
        order = np.argsort(pairs[:, 0], kind="stable")
        pairs = pairs[order]
        return pairs[:, 0].astype(np.int64), pairs[:, 1:4], pairs[:, 4:7]

    def summary(self) -> dict[str, Any]:
        """Relative RMS error during contact, raw and against the filtered true force."""
        _, estimate, true = self.arrays()
        contact = np.linalg.norm(true, axis=1) > self.config.contact_threshold_n
        result: dict[str, Any] = {
            "paired_samples": int(true.shape[0]),
            "contact_samples": int(contact.sum()),
            "contact_threshold_n": self.config.contact_threshold_n,
            "no_force_estimates": self.no_force,
            "rms_error_n": None,
            "rms_true_n": None,
            "relative_rms_error": None,
            "relative_rms_error_vs_filtered_true": None,
        }
        if not contact.any():
            return result
        rms_true = float(np.sqrt(np.mean(np.sum(true[contact] ** 2, axis=1))))
        rms_error = float(np.sqrt(np.mean(np.sum((estimate - true)[contact] ** 2, axis=1))))
        a = math.exp(-2.0 * math.pi * self.config.filter_cutoff_hz * self.config.sample_period_s)
        filtered = np.empty_like(true)
        state = true[0]
        for k in range(true.shape[0]):
            state = a * state + (1.0 - a) * true[k]
            filtered[k] = state
        rms_lagged = float(np.sqrt(np.mean(np.sum((estimate - filtered)[contact] ** 2, axis=1))))
        result.update(
            rms_error_n=round(rms_error, 6),
            rms_true_n=round(rms_true, 6),
            relative_rms_error=round(rms_error / rms_true, 6) if rms_true > 0 else None,
            relative_rms_error_vs_filtered_true=round(rms_lagged / rms_true, 6)
            if rms_true > 0
            else None,
        )
        return result


def _bounded_put(
    table: dict[int, tuple[float, float, float]], key: int, value: tuple[float, float, float]
) -> None:
    if len(table) >= _MAX_PENDING:
        table.pop(next(iter(table)))
    table[key] = value
