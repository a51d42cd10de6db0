"""Whether the force service adapts its model online, and on what.

:class:`AdaptationState` is the switch of the service's
:class:`~teleop_force.service.adaptation.AdaptationWorker`: off, on, or unavailable (with the
reason) for the model running. The worker is made the first time adaptation is switched on;
its thread runs while adaptation is on and is stopped on off (after adapting on what was
queued and installing the result), when another model is loaded (the worker is dropped, made
anew for the new model if adaptation stays on) and when the service closes.
"""

from __future__ import annotations

from typing import Any

from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.service.adaptation import (
    AdaptationGate,
    AdaptationWorker,
    adaptation_unavailable_reason,
)


class AdaptationState:
    """Online adaptation of the running estimator: its worker, on or off, why unavailable.

    Attributes:
        adaptation: The worker (``None`` until switched on for the running estimator).
        enabled: Whether each sample is handed to the worker.
        note: Why the running model cannot be adapted (empty: it can).
        gate: Which samples are adapted on (free motion, see
            :mod:`teleop_force.service.adaptation`).

    The methods are called with the service's lock held (the worker never takes it).

    """

    __slots__ = ("adaptation", "enabled", "gate", "note")

    def __init__(self, estimator: ForceEstimator, gate: AdaptationGate | None = None) -> None:
        """Start switched off for ``estimator``."""
        self.adaptation: AdaptationWorker | None = None
        self.enabled = False
        self.gate = gate if gate is not None else AdaptationGate()
        self.note = adaptation_unavailable_reason(estimator) or ""

    def switch(self, on: bool, estimator: ForceEstimator) -> None:
        """Switch adaptation of ``estimator`` on or off; raise ConfigurationError if impossible."""
        worker = self.adaptation
        if not on:
            self.enabled = False
            if worker is not None:
                worker.stop(flush=True)
                worker.apply()
            return
        if worker is None:
            worker = self.adaptation = AdaptationWorker(estimator, self.gate)
        worker.start()
        self.enabled = True

    def follow(self, estimator: ForceEstimator) -> None:
        """Move to a newly loaded ``estimator``: on if it was and the new one can be adapted."""
        if self.adaptation is not None:
            self.adaptation.stop(flush=False)  # its model is no longer run
        note = adaptation_unavailable_reason(estimator) or ""
        enabled = self.enabled and not note
        self.adaptation = AdaptationWorker(estimator, self.gate) if enabled else None
        if self.adaptation is not None:
            self.adaptation.start()
        self.enabled = enabled
        self.note = note

    def close(self) -> None:
        """Stop the worker thread (the service closes; what is queued is dropped)."""
        if self.adaptation is not None:
            self.adaptation.stop(flush=False)
        self.enabled = False

    def to_dict(self) -> dict[str, Any]:
        """Return the ``adaptation`` statistics."""
        worker = self.adaptation
        counters = (
            worker.stats()
            if worker is not None
            else {
                "samples": 0, "skipped_contact": 0, "pending": 0, "dropped": 0, "batches": 0,
                "publications": 0, "errors": 0, "last_error": "", "batch_ms": None,
                "force_threshold_n": self.gate.force_threshold_n, "guard_s": self.gate.guard_s,
            }
        )  # fmt: skip
        return {
            "enabled": self.enabled,
            "available": not self.note,
            "note": self.note,
            **counters,
        }
