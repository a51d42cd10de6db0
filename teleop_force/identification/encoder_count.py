"""A robot's encoder count, measured on its recordings, and the estimator that goes with it.

The count observer (:mod:`~teleop_force.estimation.count_observer`) clips its angles to the
count of each reading, so it needs the count of each joint: the smallest step between
consecutive readings of the recordings (:func:`measured_count_rad`). With angles that move
between the counts, the estimator can be faster than on the readings:
:func:`with_count_observer` sets both. Chosen on plant family one, seeds 1-3; held out on
family two (docs/accuracy/low_speed.md, tenth session).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from teleop_force.errors import DataError
from teleop_force.identification.filtered_regressor import FilterConfig

#: The momentum observer's bandwidth on the count observer's angles [Hz].
COUNT_OBSERVER_HZ = 400.0
#: Each of its two pre-filter stages [Hz].
COUNT_PREFILTER_HZ = 150.0
#: Its pre-filter stages.
COUNT_PREFILTER_STAGES = 2
#: The second-order Butterworth on its estimate [Hz].
COUNT_OUTPUT_HZ = 40.0
#: Steps smaller than this are not counts (rounding of a stored angle) [rad].
_SMALLEST_STEP_RAD = 1e-12


def measured_count_rad(q_rad: np.ndarray | Sequence[np.ndarray]) -> np.ndarray:
    """Return the encoder count of each joint: the smallest step between consecutive readings (n,).

    ``q_rad``: one recording's angles (N, n), or several recordings' (each its own steps).
    Raises DataError naming the joint whose angles never change (no count to measure).
    """
    several = not isinstance(q_rad, np.ndarray) and all(np.ndim(q) == 2 for q in q_rad)
    recordings = list(q_rad) if several else [np.asarray(q_rad, dtype=float)]
    steps = []
    for q in recordings:
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[0] < 2:
            raise DataError(f"need at least two samples of (N, n) angles, got shape {q.shape}")
        steps.append(np.abs(np.diff(q, axis=0)))
    stacked = np.concatenate(steps)
    counts = np.empty(stacked.shape[1])
    for j in range(stacked.shape[1]):
        moved = stacked[:, j][stacked[:, j] > _SMALLEST_STEP_RAD]
        if moved.size == 0:
            raise DataError(f"joint {j + 1}: the angle never changes, so no count to measure")
        counts[j] = float(moved.min())
    return counts


def with_count_observer(config: FilterConfig, count_rad: Sequence[float]) -> FilterConfig:
    """Return ``config`` estimating on the count observer's angles, at its bandwidth.

    The momentum observer at :data:`COUNT_OBSERVER_HZ` on two :data:`COUNT_PREFILTER_HZ`
    stages, a :data:`COUNT_OUTPUT_HZ` Butterworth on its estimate, and ``count_rad``.
    """
    return dataclasses.replace(
        config,
        estimator="observer",
        observer_hz=COUNT_OBSERVER_HZ,
        observer_prefilter_hz=COUNT_PREFILTER_HZ,
        observer_prefilter_stages=COUNT_PREFILTER_STAGES,
        observer_output_hz=COUNT_OUTPUT_HZ,
        count_observer=True,
        count_rad=tuple(float(c) for c in count_rad),
    )
