"""The external torque the residual watch tests: the model's, by the watch's own estimator.

The watch's test (:mod:`~teleop_force.service.residual_watch`) was calibrated on one estimate:
its 7 % threshold, its alpha and its anti-aliasing row means assume the noise and the slow
misfit of the momentum observer at :data:`WATCH_OBSERVER_HZ` (24 Hz) on one pre-filter
stage at the model's ``L_v``. A faster estimator (the observer at 40 Hz on two 40 Hz stages)
makes better forces but carries more slow misfit in free motion, which the test cannot tell
from a change. So the estimator the service publishes with is the user's choice, and the
watch computes its own residual from the joint states, always with that estimator: what it
reports does not depend on the bandwidth chosen for the forces.

:class:`WatchResidual` runs in the watch's thread, once a second, on the samples decoded
since its last call, with the :class:`~teleop_force.estimation.batch.BatchEstimator` (compiled,
the GIL released; about 8 ms per second of stream with the shipped model): nothing of it runs
on the 1 kHz path. Its filters restart at each call on the last
:attr:`WatchResidual.context_samples` samples of the previous one (0.5 s: 25 time constants of
the slowest filter, ``L`` at the paper's 8 Hz), so the pieces equal one continuous stream to
1e-9 (tested); a stream restart (a new run of the watch) restarts them as the service's would.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.estimation.batch import BatchEstimates, BatchEstimator
from teleop_force.estimation.estimator import with_estimator
from teleop_force.identification.dynamic_model import DynamicModel

#: Bandwidth of the watch's momentum observer [Hz].
WATCH_OBSERVER_HZ: Final = 24.0
#: Samples of the previous call the filters restart on (0.5 s at 1 kHz).
DEFAULT_CONTEXT_SAMPLES: Final = 500


def watch_estimator_model(model: DynamicModel) -> DynamicModel:
    """Return ``model`` with the watch's estimator: the observer at 24 Hz on one stage at L_v.

    Without an output filter (the observer's own first-order lag only), on the readings (no
    count observer): what the watch was calibrated with.
    """
    return with_estimator(
        model, "observer", WATCH_OBSERVER_HZ,
        observer_prefilter_hz=model.filter_config.velocity_cutoff_hz,
        observer_prefilter_stages=1, observer_output_hz=0.0, count_observer=False,
    )  # fmt: skip


class WatchResidual:
    """Estimates of the watch's estimator for consecutive pieces of one joint-state stream."""

    def __init__(self, model: DynamicModel, context_samples: int = DEFAULT_CONTEXT_SAMPLES) -> None:
        """Build the batch estimator of :func:`watch_estimator_model` for ``model``."""
        if context_samples < 1:
            raise ConfigurationError(f"context_samples must be >= 1, got {context_samples}")
        self.model = watch_estimator_model(model)
        self.context_samples = int(context_samples)
        self._estimator = BatchEstimator(self.model)
        description = self.model.description()
        n = self.model.n_joints
        lo = np.asarray(description.q_min_rad, dtype=float)
        hi = np.asarray(description.q_max_rad, dtype=float)
        #: a pose inside the joint ranges, for :meth:`warm_up`
        self._q_rest: np.ndarray = 0.5 * (lo + hi) if lo.shape == hi.shape == (n,) else np.zeros(n)
        #: the previous call's last samples: times, angles, torques, run ids, run times
        self._context: tuple[np.ndarray, ...] | None = None

    def reset(self) -> None:
        """Forget the previous samples: the next call starts the filters afresh."""
        self._context = None

    def warm_up(self) -> WatchResidual:
        """Compile (or load from numba's cache) the batch estimator on 0.1 s at rest; return self.

        Run before the service declares itself up: compiled in the watch's thread, the batch
        would hold the GIL for seconds while the stream waits.
        """
        n = self.model.n_joints
        samples = 100
        t_s = np.arange(samples) * 1e-3
        q_rad = np.tile(self._q_rest, (samples, 1))
        run = np.zeros(samples, dtype=np.int64)
        self(t_s, q_rad, np.zeros((samples, n)), run, np.zeros(samples))
        self.reset()
        return self

    def __call__(
        self,
        t_s: np.ndarray,
        q_rad: np.ndarray,
        tau_nm: np.ndarray,
        run: np.ndarray,
        run_start_s: np.ndarray,
    ) -> BatchEstimates:
        """Estimate the samples that follow the previous call's (``run``: stream ids).

        ``t_s``, ``q_rad``, ``tau_nm``: the new samples (N,), (N, n), (N, n); ``run`` (N,):
        the stream each belongs to (a new id restarts the filters); ``run_start_s`` (N,):
        when that stream began, on the ``t_s`` clock. Returns the estimates of the new
        samples only. Raises DataError as :meth:`BatchEstimator.estimate`.
        """
        new = (
            np.asarray(t_s, dtype=float), np.asarray(q_rad, dtype=float),
            np.asarray(tau_nm, dtype=float), np.asarray(run), np.asarray(run_start_s, dtype=float),
        )  # fmt: skip
        parts = new if self._context is None else tuple(
            np.concatenate((old, fresh)) for old, fresh in zip(self._context, new, strict=True)
        )  # fmt: skip
        t, q, tau, runs, run_start = parts
        starts = np.flatnonzero(runs[1:] != runs[:-1]) + 1
        estimates = self._estimator.estimate(t, q, tau, starts, stream_time_s=t - run_start)
        self._context = tuple(x[-self.context_samples :] for x in parts)
        return estimates.rows(slice(t.size - new[0].size, None))
