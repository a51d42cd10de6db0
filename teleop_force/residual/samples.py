"""The samples the residual loop scores on, and the design columns at them.

The valid samples of every recording, decimated, with their held-out folds (by time blocks,
and by phase for periodic recordings), the stacked raw signals candidate variables are read
from, and the filtered columns of the base model and of candidate effects at those rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from teleop_force.errors import DataError
from teleop_force.friction.base import FrictionModel
from teleop_force.identification.effects import BasisSpec
from teleop_force.identification.pipeline import PreparedRecording, _friction_regressor
from teleop_force.lowpass import lowpass_batch
from teleop_force.residual.options import ResidualOptions
from teleop_force.residual.scoring import (
    WholeModelCheck,
    phase_block_folds,
    time_block_folds,
    trajectory_period,
)


@dataclass(frozen=True, eq=False)
class SelectedSamples:
    """Stacked, decimated valid samples of all recordings."""

    prepared: list[PreparedRecording]
    #: Selected sample indices of each recording.
    rows: list[np.ndarray]
    #: Fold of each selected sample (time blocks).
    folds: np.ndarray
    #: All samples of all recordings, stacked: time [s], angles [rad], velocities [rad/s].
    t_s: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    #: The stage-one rigid-body torque [N m], stacked (the effects' load variable).
    load_nm: np.ndarray
    #: The same per recording.
    loads: list[np.ndarray]
    #: Filtered candidate columns at the selected rows (:func:`filtered_columns`).
    cache: dict[BasisSpec, np.ndarray] = field(default_factory=dict)
    #: Folds by phase (None unless every recording is periodic, :func:`trajectory_period`).
    phase_folds: np.ndarray | None = None

    @property
    def holdout_folds(self) -> tuple[np.ndarray, int] | None:
        """Folds of the data an effect was not found on, and their count (None: no such data).

        With several recordings, one fold per recording (an effect found on the others must
        hold on it); else the blocks by phase of a periodic recording; else None.
        """
        if len(self.rows) > 1:
            return np.repeat(np.arange(len(self.rows)), [r.size for r in self.rows]), len(self.rows)
        if self.phase_folds is not None:
            return self.phase_folds, int(self.phase_folds.max()) + 1
        return None

    @property
    def stacked_rows(self) -> np.ndarray:
        """Indices of the selected samples in the stacked signals."""
        offsets = np.cumsum([0] + [p.signals.n_samples for p in self.prepared[:-1]])
        return np.concatenate([idx + o for idx, o in zip(self.rows, offsets, strict=True)])


def select_samples(
    prepared: Sequence[PreparedRecording], options: ResidualOptions, base_values: np.ndarray
) -> SelectedSamples:
    """Decimate the valid samples and deal them to folds; ``base_values``: stage-one body."""
    rows, fold_ids, phase_ids = [], [], []
    t, q, qd, loads = [], [], [], []
    for item in prepared:
        s = item.signals
        idx = np.flatnonzero(s.valid)[:: options.decimate]
        if idx.size < options.folds * 10:
            raise DataError("recording too short for held-out blocks", path=item.recording.source)
        rows.append(idx)
        fold_ids.append(time_block_folds(idx.size, options))
        period = (
            trajectory_period(s.t_s[s.valid], s.q_rad[s.valid]) if options.phase_folds else None
        )
        if period is not None:
            phase_ids.append(phase_block_folds(s.t_s[idx], period, options))
        t.append(s.t_s)
        q.append(s.q_rad)
        qd.append(s.qd_rad_s)
        loads.append(np.einsum("kjp,p->kj", s.rigid_regressor, base_values))
    phase_folds = np.concatenate(phase_ids) if len(phase_ids) == len(rows) else None
    return SelectedSamples(
        list(prepared),
        rows,
        np.concatenate(fold_ids),
        t_s=np.concatenate(t),
        q_rad=np.concatenate(q),
        qd_rad_s=np.concatenate(qd),
        load_nm=np.concatenate(loads),
        loads=loads,
        phase_folds=phase_folds,
    )


def filtered_columns(samples: SelectedSamples, spec: BasisSpec) -> np.ndarray:
    """Low-pass filter the candidate's basis per recording, at the selected rows (cached)."""
    cached = samples.cache.get(spec)
    if cached is not None:
        return cached
    out = []
    for item, idx, load in zip(samples.prepared, samples.rows, samples.loads, strict=True):
        s = item.signals
        phi = spec.basis(s.t_s, s.q_rad, s.qd_rad_s, load)
        out.append(lowpass_batch(phi, s.t_s, s.config.cutoff_hz)[idx])
    columns = np.concatenate(out)
    samples.cache[spec] = columns
    return columns


def selected_friction_regressor(samples: SelectedSamples, friction: FrictionModel) -> np.ndarray:
    """Return the filtered friction regressor at the selected rows, ``(rows, n, p_f)``."""
    return np.concatenate(
        [
            _friction_regressor(friction, item.signals)[idx]
            for item, idx in zip(samples.prepared, samples.rows, strict=True)
        ]
    )


def joint_base(
    samples: SelectedSamples,
    friction_l: np.ndarray,
    joint: int,
    offsets: bool,
    network: FrictionModel | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``joint``'s base design and filtered torque at the selected rows.

    Its friction columns are the parameters whose torque reaches the joint (``friction_l``:
    :func:`selected_friction_regressor`): its own basis for per-joint friction, the laws
    reaching it through the coupling for friction in model coordinates.
    """
    own = friction_l[:, joint, :]
    rigid, rest, ys = [], [], []
    for item, idx in zip(samples.prepared, samples.rows, strict=True):
        s = item.signals
        rigid.append(s.rigid_regressor[idx, joint, :])
        parts = []
        if network is not None:
            psi = lowpass_batch(network.basis(joint, s.qd_rad_s), s.t_s, s.config.cutoff_hz)
            parts.append(psi[idx])
        if offsets:
            parts.append(np.ones((idx.size, 1)))
        rest.append(np.concatenate(parts, axis=1) if parts else np.zeros((idx.size, 0)))
        ys.append(s.tau_lowpassed_nm[idx, joint])
    columns = (np.concatenate(rigid), own[:, np.any(own != 0.0, axis=0)], np.concatenate(rest))
    return np.concatenate(columns, axis=1), np.concatenate(ys)


def whole_model_check(
    samples: SelectedSamples,
    friction_l: np.ndarray,
    offsets: bool,
    options: ResidualOptions,
    folds: np.ndarray,
    n_folds: int | None = None,
) -> WholeModelCheck:
    """Return the whole model's design at the selected rows: rigid body, friction, offsets.

    The friction is the stage-one model's (a wavelet network's coupled CV fallback): a
    velocity map does not extrapolate to blocks held out by phase. ``n_folds``: the number
    of ``folds`` (default ``options.folds``).
    """
    n = friction_l.shape[1]
    pairs = list(zip(samples.prepared, samples.rows, strict=True))
    rigid = np.concatenate([p.signals.rigid_regressor[idx] for p, idx in pairs])
    y = np.concatenate([p.signals.tau_lowpassed_nm[idx] for p, idx in pairs])
    parts = [rigid, friction_l[:, :, np.any(friction_l != 0.0, axis=(0, 1))]]
    if offsets:
        parts.append(np.broadcast_to(np.eye(n), (rigid.shape[0], n, n)))
    count = options.folds if n_folds is None else n_folds
    return WholeModelCheck(np.concatenate(parts, axis=2), y, folds, count, options.ridge)
