"""Whether the force service adapts its model online, and on what.

:class:`AdaptationState` is the switch of the service's
:class:`~teleop_force.service.adaptation.OnlineAdaptation`: off, on, or unavailable (with the
reason) for the model running. The driver is made the first time adaptation is switched on,
and made anew (or dropped) when another model is loaded.
"""

from __future__ import annotations

from typing import Any

from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.service.adaptation import OnlineAdaptation, adaptation_unavailable_reason


class AdaptationState:
    """Online adaptation of the running estimator: its driver, on or off, why unavailable.

    Attributes:
        adaptation: The driver (``None`` until switched on for the running estimator).
        enabled: Whether each sample is adapted on.
        note: Why the running model cannot be adapted (empty: it can).

    """

    __slots__ = ("adaptation", "enabled", "note")

    def __init__(self, estimator: ForceEstimator) -> None:
        """Start switched off for ``estimator``."""
        self.adaptation: OnlineAdaptation | None = None
        self.enabled = False
        self.note = adaptation_unavailable_reason(estimator) or ""

    def switch(self, on: bool, estimator: ForceEstimator) -> None:
        """Switch adaptation of ``estimator`` on or off; raise ConfigurationError if impossible."""
        if not on:
            self.enabled = False
            return
        if self.adaptation is None:
            self.adaptation = OnlineAdaptation(estimator)
        self.enabled = True

    def follow(self, estimator: ForceEstimator) -> None:
        """Move to a newly loaded ``estimator``: on if it was and the new one can be adapted."""
        note = adaptation_unavailable_reason(estimator) or ""
        enabled = self.enabled and not note
        self.adaptation = OnlineAdaptation(estimator) if enabled else None
        self.enabled = enabled
        self.note = note

    def to_dict(self) -> dict[str, Any]:
        """Return the ``adaptation`` statistics."""
        return {
            "enabled": self.enabled,
            "available": not self.note,
            "note": self.note,
            "samples": 0 if self.adaptation is None else self.adaptation.samples,
        }
