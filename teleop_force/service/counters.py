"""Counters of the force service, each feeding its part of the ``service/stats`` JSON.

* :class:`JointStateCounters`: the joint states received (sequence tracking, rate, overflow);
* :class:`EstimateCounters`: the estimates published (counts, latency and processing
  histograms, share on trained ground, the last one);
* :class:`MalformedCounter`: the malformed messages dropped, by key, in a bounded table;
* :class:`ControlCounters`: the run-time control requests (model loads, refusals).

They hold numbers only: the service updates them under its lock and reads them back for
:meth:`~teleop_force.service.force_service.ForceService.stats`.
"""

from __future__ import annotations

import math
import time
from typing import Any, Final

from teleop_force.transport.stream_stats import LatencyHistogram, RateMeter, SequenceTracker

#: Keys counted apart in ``malformed.by_key`` at most; further keys are counted together.
MAX_COUNTED_KEYS: Final = 64
OTHER_KEYS: Final = "(other keys)"


class JointStateCounters:
    """Joint states received: sequence gaps and restarts, rate, and those dropped on overflow.

    Attributes:
        seqs: Sequence tracking of the joint states (received, lost, restarts, duplicates).
        rate: Rate of the joint states estimated on (duplicates left out).
        overflow: Joint states dropped because the estimator's backlog was full.

    """

    __slots__ = ("overflow", "rate", "seqs")

    def __init__(self) -> None:
        """Start at zero."""
        self.seqs = SequenceTracker()
        self.rate = RateMeter()
        self.overflow = 0

    def to_dict(self, *, stream_restarts: int, backlog: int) -> dict[str, Any]:
        """Return the ``joint_states`` statistics (with the clock's restarts and the backlog)."""
        return {
            **self.seqs.to_dict(),
            "stream_restarts": stream_restarts,
            "backlog": backlog,
            "overflow_dropped": self.overflow,
            "rate_hz": round(self.rate.rate_hz, 2),
            "mean_rate_hz": round(self.rate.mean_rate_hz, 2),
        }


class EstimateCounters:
    """Estimates published and failed, their latencies, and how often on trained ground.

    Attributes:
        published: Estimates published (the next one's ``seq`` is this, mod 2**32).
        singular: Estimates with a Jacobian too close to singular for a force.
        errors: Estimates that could not be computed (or the estimator thread failed).
        last_error: The last of those errors.
        latency: Joint-state stamp -> estimate publish [s].
        processing: Time spent estimating and publishing one joint state [s].
        on_ground_all: Estimates with every joint on trained ground.
        on_ground_joint: Per joint, estimates with that joint on trained ground.
        last_source_seq: ``source_seq`` of the last estimate published (-1: none yet).
        last_force: ``f_n`` of the last estimate published.

    """

    __slots__ = (
        "errors",
        "last_error",
        "last_force",
        "last_source_seq",
        "latency",
        "on_ground_all",
        "on_ground_joint",
        "processing",
        "published",
        "singular",
    )

    def __init__(self, n_joints: int) -> None:
        """Start at zero for a device of ``n_joints`` joints."""
        self.published = 0
        self.singular = 0
        self.errors = 0
        self.last_error = ""
        self.latency = LatencyHistogram()
        self.processing = LatencyHistogram()
        self.on_ground_all = 0
        self.on_ground_joint = [0] * n_joints
        self.last_source_seq = -1
        self.last_force: list[float] = []

    def count_published(
        self,
        source_seq: int,
        force: list[float],
        on_ground_mask: int,
        n_joints: int,
        singular: bool,
        stamp_ns: int,
        started_s: float,
    ) -> None:
        """Count an estimate just published for a joint state.

        ``force``: its ``f_n``; ``on_ground_mask``: bit ``j`` set when joint ``j`` is on
        trained ground; ``stamp_ns``: the joint state's stamp (latency measured from it, to
        now); ``started_s``: ``time.perf_counter()`` when its processing began.
        """
        self.published += 1
        self.latency.add((time.time_ns() - stamp_ns) * 1e-9)
        if singular:
            self.singular += 1
        if on_ground_mask:
            joints = self.on_ground_joint
            for j in range(n_joints):
                if on_ground_mask >> j & 1:
                    joints[j] += 1
        if on_ground_mask == (1 << n_joints) - 1:
            self.on_ground_all += 1
        self.last_source_seq = source_seq
        self.last_force = force
        self.processing.add(time.perf_counter() - started_s)

    def count_error(self, error: str) -> None:
        """Count an estimate that could not be made, and why."""
        self.errors += 1
        self.last_error = error

    def to_dict(self) -> dict[str, Any]:
        """Return the ``estimates`` statistics."""
        return {
            "published": self.published,
            "singular": self.singular,
            "errors": self.errors,
            "last_error": self.last_error,
        }

    def on_ground_fraction(self) -> float | None:
        """Share of the estimates with every joint on trained ground (``None``: none yet)."""
        return _fraction(self.on_ground_all, self.published)

    def on_ground_fraction_per_joint(self) -> list[float | None]:
        """Per joint, the share of the estimates with that joint on trained ground."""
        return [_fraction(int(c), self.published) for c in self.on_ground_joint]

    def last_estimate_dict(self) -> dict[str, Any] | None:
        """Return the ``last_estimate`` statistics: its source ``seq`` and force (NaN: null)."""
        if self.last_source_seq < 0:
            return None
        return {
            "source_seq": self.last_source_seq,
            "f_n": [None if math.isnan(x) else x for x in self.last_force],
        }


class MalformedCounter:
    """Malformed messages dropped, by key, and the last one.

    At most ``max_keys`` keys are counted apart; messages on further keys are counted together
    under :data:`OTHER_KEYS`, so a flood on ever new keys cannot grow the table without end.

    Attributes:
        by_key: Messages dropped per key.
        last: ``"<key>: <error>"`` of the last one (empty: none yet).
        max_keys: Keys counted apart at most.

    """

    __slots__ = ("by_key", "last", "max_keys")

    def __init__(self, max_keys: int = MAX_COUNTED_KEYS) -> None:
        """Start with an empty table of at most ``max_keys`` keys (and the other keys)."""
        self.by_key: dict[str, int] = {}
        self.last = ""
        self.max_keys = max_keys

    def count(self, key: str, error: Exception) -> None:
        """Count one malformed message received on ``key``."""
        by_key = self.by_key
        if key not in by_key and len(by_key) >= self.max_keys:
            key = OTHER_KEYS
        by_key[key] = by_key.get(key, 0) + 1
        self.last = f"{key}: {error}"

    @property
    def dropped(self) -> int:
        """Malformed messages dropped in all."""
        return sum(self.by_key.values())

    def to_dict(self) -> dict[str, Any]:
        """Return the ``malformed`` statistics."""
        return {"dropped": self.dropped, "by_key": dict(self.by_key), "last": self.last}


class ControlCounters:
    """Run-time control requests: answered, refused (and why), model loads done.

    Attributes:
        requests: Well-formed requests (a plain model fetch is not one).
        refused: Requests refused, malformed ones included.
        last_refusal: Why the last one was refused.
        loads: Models loaded at run time.

    """

    __slots__ = ("last_refusal", "loads", "refused", "requests")

    def __init__(self) -> None:
        """Start at zero."""
        self.requests = 0
        self.refused = 0
        self.last_refusal = ""
        self.loads = 0

    def count_refusal(self, error: str) -> None:
        """Count a refused request, and why."""
        self.refused += 1
        self.last_refusal = error

    def to_dict(self) -> dict[str, Any]:
        """Return the ``controls`` statistics (the loads are reported under ``model``)."""
        return {
            "requests": self.requests,
            "refused": self.refused,
            "last_refusal": self.last_refusal,
        }


def _fraction(count: int, total: int) -> float | None:
    return None if total == 0 else round(count / total, 6)
