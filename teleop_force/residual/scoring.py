"""Held-out scoring of the residual loop: blocks, folds, per-joint designs, the whole model.

The valid samples of each recording are cut into ``folds * blocks_per_fold`` contiguous time
blocks, dealt to ``folds`` folds in turn (:func:`time_block_folds`), so a sweep's every region
is seen in training and in held-out data. A candidate effect is scored by blocked
cross-validation (fit on the other blocks, error on the held-out block), computed from
per-block normal equations (:class:`JointDesign`) so hundreds of candidates cost little.

The per-joint designs give each joint its own copy of the rigid-body parameters; the kept
model shares them, so candidates are confirmed in the whole model (:class:`WholeModelCheck`).
A periodic recording (:func:`trajectory_period`) is also cut by phase
(:func:`phase_block_folds`): a held-out block is then the same stretch of every period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from teleop_force.residual.options import ResidualOptions
from teleop_force.residual.placement import placed_columns


def held_out_gain(base_errors: np.ndarray, errors: np.ndarray) -> float:
    """Relative drop of the held-out RMS from per-fold squared errors ``base_errors``."""
    return float(1.0 - np.sqrt(errors.sum() / max(base_errors.sum(), 1e-300)))


class JointDesign:
    """Held-out scoring of candidate columns for one joint from per-fold normal equations."""

    def __init__(
        self,
        base: np.ndarray,
        y: np.ndarray,
        folds: np.ndarray,
        n_folds: int,
        ridge: float,
        reference_energy: float | None = None,
    ) -> None:
        self.y = y
        self.folds = folds
        self.n_folds = n_folds
        self.ridge = ridge
        self._masks = [folds == f for f in range(n_folds)]
        self.yy = np.array([float(y[m] @ y[m]) for m in self._masks])
        #: What :meth:`relative_rms` divides by: the sum of squares of ``y``, or of the torque
        #: when ``y`` is a residual against a fixed model (``reference_energy``).
        self.reference_energy = (
            float(self.yy.sum()) if reference_energy is None else reference_energy
        )
        self._set_base(base)

    def _set_base(self, base: np.ndarray) -> None:
        self.base = base
        self.gram = [base[m].T @ base[m] for m in self._masks]
        self.cross = [base[m].T @ self.y[m] for m in self._masks]
        self._base_errors: np.ndarray | None = None

    def add(self, columns: np.ndarray) -> None:
        """Make ``columns`` part of the base."""
        self._set_base(np.concatenate((self.base, columns), axis=1))

    def with_columns(self, columns: np.ndarray) -> JointDesign:
        """Return a new design: this one's base and ``columns``, the same ``y`` and reference."""
        return JointDesign(
            np.concatenate((self.base, columns), axis=1),
            self.y,
            self.folds,
            self.n_folds,
            self.ridge,
            reference_energy=self.reference_energy,
        )

    def _score(self, grams: list[np.ndarray], crosses: list[np.ndarray]) -> np.ndarray:
        g_all = sum(grams)
        c_all = sum(crosses)
        errors = np.empty(self.n_folds)
        for f in range(self.n_folds):
            g = g_all - grams[f]
            c = c_all - crosses[f]
            if g.shape[0] == 0:  # nothing to fit: the held-out error is the signal's own
                errors[f] = self.yy[f]
                continue
            scale = np.sqrt(np.clip(np.diag(g), 1e-300, None))
            gs = g / np.outer(scale, scale) + self.ridge * np.eye(len(scale))
            try:
                factor = scipy.linalg.cho_factor(gs, check_finite=False)
                theta = scipy.linalg.cho_solve(factor, c / scale, check_finite=False) / scale
            except np.linalg.LinAlgError:
                theta = np.linalg.lstsq(gs, c / scale, rcond=None)[0] / scale
            errors[f] = self.yy[f] - 2 * theta @ crosses[f] + theta @ grams[f] @ theta
        return np.clip(errors, 0.0, None)

    def held_out_errors(self, candidate: np.ndarray | None = None) -> np.ndarray:
        """Held-out squared error per fold, with ``candidate`` columns added if given."""
        if candidate is None:
            if self._base_errors is None:
                self._base_errors = self._score(self.gram, self.cross)
            return self._base_errors
        grams, crosses = [], []
        for f, m in enumerate(self._masks):
            b, c = self.base[m], candidate[m]
            bc = b.T @ c
            grams.append(np.block([[self.gram[f], bc], [bc.T, c.T @ c]]))
            crosses.append(np.concatenate((self.cross[f], c.T @ self.y[m])))
        return self._score(grams, crosses)

    def relative_rms(self, errors: np.ndarray) -> float:
        """Held-out relative RMS from per-fold squared errors."""
        return float(np.sqrt(errors.sum() / max(self.reference_energy, 1e-300)))

    def residual(self) -> np.ndarray:
        """Residual of the least-squares fit of the base on all rows."""
        if self.base.shape[1] == 0:
            return self.y
        theta = np.linalg.lstsq(self.base, self.y, rcond=None)[0]
        return self.y - self.base @ theta


class WholeModelCheck:
    """Held-out relative RMS per joint of the whole model: one rigid body for all joints.

    The per-joint designs give each joint its own copy of the rigid-body parameters, which is
    what makes scoring hundreds of candidates cheap, but a joint's copy can bend to what a
    candidate offers; the model that is kept shares them. A candidate the search accepts is
    therefore confirmed here, on the same held-out blocks.
    """

    def __init__(
        self,
        columns: np.ndarray,
        y: np.ndarray,
        folds: np.ndarray,
        n_folds: int,
        ridge: float,
        reference_energy: np.ndarray | None = None,
    ) -> None:
        self.columns = columns  # (rows, n, p)
        self.y = y  # (rows, n)
        self.folds = folds
        self.n_folds = n_folds
        self.ridge = ridge
        # What the relative RMS divides by: y's energy per joint, or the torque's when y is a
        # residual against a fixed model.
        energy = np.sum(y**2, axis=0) if reference_energy is None else reference_energy
        self._yy = np.clip(energy, 1e-300, None)
        self._base: np.ndarray | None = None

    def add(self, extra: np.ndarray) -> None:
        """Make ``extra`` ``(rows, n, k)`` part of the model."""
        self.columns = np.concatenate((self.columns, extra), axis=2)
        self._base = None

    def relative_rms(self, extra: np.ndarray | None = None) -> np.ndarray:
        """Held-out relative RMS per joint, with ``extra`` columns if given."""
        if extra is None and self._base is not None:
            return self._base
        a = self.columns if extra is None else np.concatenate((self.columns, extra), axis=2)
        _, n, p = a.shape
        squared = np.zeros(n)
        for f in range(self.n_folds):
            held = self.folds == f
            if p == 0:  # nothing to fit: the held-out error is the signal's own
                squared += np.sum(self.y[held] ** 2, axis=0)
                continue
            train = a[~held].reshape(-1, p)
            gram = train.T @ train
            scale = np.sqrt(np.clip(np.diag(gram), 1e-300, None))
            scaled = gram / np.outer(scale, scale) + self.ridge * np.eye(p)
            cross = train.T @ self.y[~held].reshape(-1) / scale
            try:
                theta = scipy.linalg.solve(scaled, cross, assume_a="pos", check_finite=False)
            except np.linalg.LinAlgError:
                theta = np.linalg.lstsq(scaled, cross, rcond=None)[0]
            error = self.y[held] - a[held] @ (theta / scale)
            squared += np.sum(error**2, axis=0)
        out = np.sqrt(squared / self._yy)
        if extra is None:
            self._base = out
        return out


#: A joint whose held-out relative RMS is above this is not explained by the model (noise or
#: what no candidate has yet taken): whether a candidate makes it worse is not judged on it.
EXPLAINED_LIMIT = 0.5


def worse_joints(before: np.ndarray, after: np.ndarray, tolerance: float) -> np.ndarray:
    """Joints the model explains (:data:`EXPLAINED_LIMIT`) whose error rose by ``tolerance``."""
    return (before < EXPLAINED_LIMIT) & (after > before * (1.0 + tolerance))


@dataclass(frozen=True, eq=False)
class Confirmation:
    """Outcome of checking a candidate against the whole model (:func:`confirm`)."""

    confirmed: bool
    #: Motor torque per unit of the effect's torque (None: on its joint alone).
    reach: np.ndarray | None
    #: Relative drop of the joint's whole-model held-out RMS.
    gain: float
    #: Explained joints (1-based) it made worse, on time or phase blocks.
    worse_joints: tuple[int, ...]
    #: Whole-model held-out relative RMS per joint with the candidate.
    after: tuple[float, ...]
    #: Relative drop of the joint's RMS on the data it was not found on (another recording,
    #: or blocks held out by phase; None: no such data).
    holdout_gain: float | None = None


def confirm(
    check: WholeModelCheck,
    veto: WholeModelCheck | None,
    before: np.ndarray,
    cols: np.ndarray,
    joint: int,
    reach: np.ndarray | None,
    alone_too: bool,
    options: ResidualOptions,
) -> Confirmation:
    """Check a candidate against the whole model: at its model joint first, then alone.

    A placement is confirmed when it lowers ``joint``'s held-out RMS by ``min_rms_gain`` and
    raises no explained joint's (:func:`worse_joints`) by more than that, and (``veto``: the
    same model on data the effect was not found on: another recording, or blocks held out
    by phase) lowers ``joint``'s RMS there by ``min_holdout_gain`` and raises no explained
    joint's by more than ``min_rms_gain`` either: an effect that only fits the poses of a
    repeated trajectory fails there. The model joint (``reach``) is kept when it is
    confirmed; ``joint`` alone is tried after it when ``alone_too`` (or without a ``reach``).
    Returns the confirmed placement or the last one tried.
    """
    placements: tuple[np.ndarray | None, ...] = (None,)
    if reach is not None:
        placements = (reach, None) if alone_too else (reach,)
    for placement in placements:
        placed = placed_columns(cols, joint, placement, len(before))
        after = check.relative_rms(placed)
        gain = 1.0 - after[joint] / max(before[joint], 1e-300)
        worse = worse_joints(before, after, options.min_rms_gain)
        holdout_gain = None
        if veto is not None:
            veto_before, veto_after = veto.relative_rms(), veto.relative_rms(placed)
            worse |= worse_joints(veto_before, veto_after, options.min_rms_gain)
            holdout_gain = float(1.0 - veto_after[joint] / max(veto_before[joint], 1e-300))
        holds = holdout_gain is None or holdout_gain >= options.min_holdout_gain
        result = Confirmation(
            confirmed=bool(gain >= options.min_rms_gain and holds and not worse.any()),
            reach=placement,
            gain=float(gain),
            worse_joints=tuple(int(k) + 1 for k in np.flatnonzero(worse)),
            after=tuple(after.tolist()),
            holdout_gain=holdout_gain,
        )
        if result.confirmed:
            break
    return result


def time_block_folds(size: int, options: ResidualOptions) -> np.ndarray:
    """Fold of each of ``size`` samples: contiguous time blocks dealt to the folds in turn."""
    n_blocks = options.folds * options.blocks_per_fold
    block = (np.arange(size) * n_blocks) // size
    return block % options.folds


def phase_block_folds(t_s: np.ndarray, period_s: float, options: ResidualOptions) -> np.ndarray:
    """Fold of each sample at times ``t_s``: blocks of the phase within ``period_s``.

    ``options.phase_blocks_per_fold`` contiguous blocks per fold, dealt in turn.
    """
    n_blocks = options.folds * options.phase_blocks_per_fold
    phase = np.mod(t_s - t_s[0], period_s) / period_s
    phase_block = np.minimum((phase * n_blocks).astype(int), n_blocks - 1)
    return phase_block % options.folds


#: Largest RMS difference between the angles and the angles one period later, relative to
#: their spread, for a recording to count as periodic.
PERIOD_TOLERANCE = 0.1


def trajectory_period(
    t_s: np.ndarray, q_rad: np.ndarray, min_period_s: float = 1.0
) -> float | None:
    """Period of a repeated trajectory [s], or None when the angles do not repeat.

    The shortest lag (at least ``min_period_s``, at most half the recording, so two periods
    are seen) at which the angles come back to themselves: a local minimum of
    ``rms(q(t + L) - q(t))`` (each moving joint scaled by its spread) below
    :data:`PERIOD_TOLERANCE`, searched on at most about 4000 samples and refined at full
    rate (the coarse step must stay well below the period: a tenth of it or less). Uniform
    sampling is assumed (the median interval converts lags to time).
    """
    t_s = np.asarray(t_s, dtype=float)
    q_rad = np.asarray(q_rad, dtype=float)
    if t_s.size < 8 or q_rad.shape[0] != t_s.size:
        return None
    dt = float(np.median(np.diff(t_s)))
    spread = q_rad.std(axis=0)
    moving = spread > 1e-6
    if not dt > 0 or not moving.any():
        return None
    q = q_rad[:, moving] / spread[moving]

    def mismatch(x: np.ndarray, lag: int) -> float:
        return float(np.sqrt(np.mean((x[lag:] - x[:-lag]) ** 2)))

    step = max(1, q.shape[0] // 4000)
    coarse = q[::step]
    first = max(1, int(np.ceil(min_period_s / (dt * step))))
    last = coarse.shape[0] // 2
    if last <= first + 1:
        return None
    lags = np.arange(first, last + 1)
    values = np.array([mismatch(coarse, int(lag)) for lag in lags])
    # The coarse lags may straddle the period: their dips are refined at full rate, shortest
    # first, and the first that comes back within the tolerance is the period.
    dips = np.flatnonzero(
        (values[1:-1] <= values[:-2])
        & (values[1:-1] <= values[2:])
        & (values[1:-1] < 5 * PERIOD_TOLERANCE)
    )
    for dip in dips:
        centre = int(lags[dip + 1]) * step
        fine = range(max(1, centre - step), min(q.shape[0] // 2, centre + step) + 1)
        lag = min(fine, key=lambda k: mismatch(q, k))
        if mismatch(q, lag) < PERIOD_TOLERANCE:
            return lag * dt
    return None
