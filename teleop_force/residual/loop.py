"""Close the loop: find the residual, trace it to the effect the model lacks, add it, report.

Every decision is made on held-out data: the valid samples of each recording are cut into
``folds * blocks_per_fold`` contiguous time blocks, dealt to ``folds`` folds in turn (so a
sweep's every region is seen in training and in held-out data); a candidate effect is scored by
blocked cross-validation (fit on the other blocks, error on the held-out block), computed from
per-block normal equations so hundreds of candidates cost little. An effect is added only when
it lowers the joint's held-out RMS by ``min_rms_gain`` (relative) and helps in most blocks; the
search then repeats until nothing significant is left.

Whole-model confirmation. The search scores each joint with its own copy of the rigid-body
parameters; the kept model shares them. The best candidates are therefore refitted in the
whole model (:class:`_JointCheck`: rigid body, stage-one friction, offsets and the effects so
far, all joints) on the same blocks, and must keep their gain without making an explained joint
worse. A periodic recording (an identification trajectory repeated, :func:`trajectory_period`)
is also cut by phase: a held-out block is then the same stretch of every period, so its poses
are held out in all of them (with time blocks, the same poses a period later are in the
training blocks, and a pattern of the trajectory's poses passes for an effect). An effect that
raises an explained joint's phase-held-out error is refused (phase blocks only veto: they are
too strict to decide, an effect's variable may not reach a held-out phase's values elsewhere).

Candidates are linear in their parameters (:mod:`teleop_force.identification.effects`): smooth or
periodic
functions of any joint angle or angle difference (optionally direction-modulated: position
dependent friction), of other joints' velocities (coupling), of the motor torque (load
dependent friction), of time (drift), Stribeck-like low-speed shapes and offsets.

Friction controls. With a wavelet network mapping a joint's velocities, a candidate on another
variable must also lower the held-out error with friction-shaped stand-ins in the model
(smooth functions of the mapped velocities, Stribeck and bearing-load terms, and the
transients after a motion reversal, :func:`reversal_transient_basis`): on a periodic
trajectory every variable correlates with the velocities, and friction the static velocity
map cannot follow (the velocity estimate lags the true velocity at a reversal, where dry
friction flips) would otherwise be named after the joint angle at which the reversals happen.

Effects at the model joints (``effect_placement``). With friction in model coordinates
(``model-cv``) the robot's physics is taken to act at its model joints first: an effect found
on motor ``j`` is tried as a torque at model joint ``j``, reaching the motors through the
coupling, ``T^T e_j`` (row ``j`` of the coupling, :attr:`FoundEffect.reach`), like the
friction, and kept there if the whole model confirms it, else on motor ``j`` alone. On the dVRK
MTM the cable/spring torque of the wrist platform is found on joint 4 and loads joints 2 and 3
with the cable's ratio (+-0.6697), instead of being left to the rigid body there. The held-out
blocks of one trajectory score the two placements about equally; a held-out trajectory does
not (docs/robots.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.linalg

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.friction.base import FrictionModel
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.model_coordinates import ModelCoordinateFriction
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, FoundEffect, variable_values
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.least_squares import least_squares
from teleop_force.identification.lowpass import lowpass_batch
from teleop_force.identification.pipeline import (
    PreparedRecording,
    _friction_regressor,
    prepare,
    stage_one_friction,
)
from teleop_force.identification.rigid_body_fit import RigidBodyFitOptions, nuisance_friction_basis
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.description import RobotDescription

#: Friction of the model the residual is taken from.
RESIDUAL_FRICTION_KINDS: tuple[str, ...] = ("cv", "coupled-cv", "wn", ModelCoordinateFriction.kind)
#: Where a found effect may act (:attr:`ResidualOptions.effect_placement`).
EFFECT_PLACEMENTS: tuple[str, ...] = ("auto", "motor", "model", "either")


@dataclass(frozen=True)
class ResidualOptions:
    """Knobs of the residual loop."""

    folds: int = 5
    blocks_per_fold: int = 4
    min_rms_gain: float = 0.05
    min_control_gain: float = 0.05
    min_fold_wins: float = 0.8
    max_effects: int = 6
    decimate: int = 5
    smooth_counts: tuple[int, ...] = (6, 12)
    modulated_counts: tuple[int, ...] = (4, 6, 8)
    harmonics: int = 2
    friction: str = "wn"
    ridge: float = 1e-4
    #: Fit a constant torque per joint; None: only without rigid-body terms.
    offsets: bool | None = None
    #: Candidates, best first, checked against the whole model per step (:class:`_JointCheck`).
    confirm_candidates: int = 20
    #: Also cut periodic recordings into held-out blocks by phase (:func:`trajectory_period`)
    #: and refuse an effect that raises a joint's error on them (:func:`_confirm`).
    phase_folds: bool = True
    #: Where an effect found on motor j acts (:data:`EFFECT_PLACEMENTS`): ``motor`` (on j
    #: alone), ``model`` (at model joint j, reaching the motors through the coupling,
    #: :func:`effect_reaches`), ``either`` (the model joint if the whole model confirms it,
    #: else j alone); ``auto``: ``either`` with friction in model coordinates, else ``motor``.
    effect_placement: str = "auto"

    def __post_init__(self) -> None:
        if self.folds < 3:
            raise ConfigurationError("folds must be >= 3")
        if not 0 < self.min_rms_gain < 1:
            raise ConfigurationError("min_rms_gain must be in (0, 1)")
        if not 0 <= self.min_control_gain < 1:
            raise ConfigurationError("min_control_gain must be in [0, 1)")
        for what, value, choices in (
            ("residual friction", self.friction, RESIDUAL_FRICTION_KINDS),
            ("effect placement", self.effect_placement, EFFECT_PLACEMENTS),
        ):
            if value not in choices:
                raise ConfigurationError(
                    f"{what} must be one of {', '.join(choices)}, got {value!r}"
                )
        if self.decimate < 1:
            raise ConfigurationError("decimate must be >= 1")
        if self.confirm_candidates < 1:
            raise ConfigurationError("confirm_candidates must be >= 1")


@dataclass(frozen=True)
class TracedEffect:
    """An effect the loop added, with its held-out figures."""

    spec: BasisSpec
    explained: float
    joint_rms_before: float
    joint_rms_after: float
    #: Motor torque per unit of the effect's torque when it acts at a model joint (None: on
    #: the joint alone).
    reach: tuple[float, ...] | None = None

    def to_json(self) -> dict[str, Any]:
        """Return the CONTRACT.md form (``reach`` only for an effect at a model joint)."""
        out: dict[str, Any] = {
            "joint": self.spec.joint + 1,
            "depends_on": self.spec.depends_on(),
            "kind": self.spec.kind,
            "explained": round(float(self.explained), 6),
            "description": self.spec.describe(),
            "joint_rms_before": float(self.joint_rms_before),
            "joint_rms_after": float(self.joint_rms_after),
        }
        if self.reach is not None:
            out["reach"] = [float(w) for w in self.reach]
        return out


@dataclass(frozen=True, eq=False)
class ResidualReport:
    """Result of :func:`trace_residual`."""

    before: np.ndarray
    after: np.ndarray
    effects: tuple[TracedEffect, ...]
    model: DynamicModel
    samples: int
    history: tuple[dict[str, Any], ...] = field(default_factory=tuple)
    plots: dict[str, Any] = field(default_factory=dict)
    rejected: tuple[dict[str, Any], ...] = field(default_factory=tuple)

    def to_json(self) -> dict[str, Any]:
        """Return the JSON object of ``teleop-force residual --json``."""
        return {
            "before": [float(x) for x in self.before],
            "after": [float(x) for x in self.after],
            "effects": [e.to_json() for e in self.effects],
            "samples": self.samples,
            "held_out": "blocked cross-validation over contiguous time blocks",
        }


class _Design:
    """Held-out scoring of candidate columns for one joint from per-fold normal equations."""

    def __init__(
        self, base: np.ndarray, y: np.ndarray, folds: np.ndarray, n_folds: int, ridge: float
    ) -> None:
        self.base = base
        self.y = y
        self.folds = folds
        self.n_folds = n_folds
        self.ridge = ridge
        self._masks = [folds == f for f in range(n_folds)]
        self.gram = [base[m].T @ base[m] for m in self._masks]
        self.cross = [base[m].T @ y[m] for m in self._masks]
        self.yy = np.array([float(y[m] @ y[m]) for m in self._masks])
        self._base_errors: np.ndarray | None = None

    def add(self, columns: np.ndarray) -> None:
        """Make ``columns`` part of the base."""
        self.__init__(  # type: ignore[misc]
            np.concatenate((self.base, columns), axis=1),
            self.y,
            self.folds,
            self.n_folds,
            self.ridge,
        )

    def _score(self, grams: list[np.ndarray], crosses: list[np.ndarray]) -> np.ndarray:
        g_all = sum(grams)
        c_all = sum(crosses)
        errors = np.empty(self.n_folds)
        for f in range(self.n_folds):
            g = g_all - grams[f]
            c = c_all - crosses[f]
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
        return float(np.sqrt(errors.sum() / max(self.yy.sum(), 1e-300)))


class _JointCheck:
    """Held-out relative RMS per joint of the whole model: one rigid body for all joints.

    The per-joint designs give each joint its own copy of the rigid-body parameters, which is
    what makes scoring hundreds of candidates cheap, but a joint's copy can bend to what a
    candidate offers; the model that is kept shares them. A candidate the search accepts is
    therefore confirmed here, on the same held-out blocks.
    """

    def __init__(
        self, columns: np.ndarray, y: np.ndarray, folds: np.ndarray, n_folds: int, ridge: float
    ) -> None:
        self.columns = columns  # (rows, n, p)
        self.y = y  # (rows, n)
        self.folds = folds
        self.n_folds = n_folds
        self.ridge = ridge
        self._yy = np.clip(np.sum(y**2, axis=0), 1e-300, None)
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


def _placed(cols: np.ndarray, joint: int, reach: np.ndarray | None, n: int) -> np.ndarray:
    """Candidate columns ``(rows, k)`` on ``joint``, or spread by ``reach``: ``(rows, n, k)``."""
    weights = np.eye(n)[joint] if reach is None else reach
    return cols[:, None, :] * weights[None, :, None]


#: A joint whose held-out relative RMS is above this is not explained by the model (noise or
#: what no candidate has yet taken): whether a candidate makes it worse is not judged on it.
EXPLAINED_LIMIT = 0.5


def _worse(before: np.ndarray, after: np.ndarray, tolerance: float) -> np.ndarray:
    """Joints the model explains (:data:`EXPLAINED_LIMIT`) whose error rose by ``tolerance``."""
    return (before < EXPLAINED_LIMIT) & (after > before * (1.0 + tolerance))


def _confirm(
    check: _JointCheck,
    veto: _JointCheck | None,
    before: np.ndarray,
    cols: np.ndarray,
    joint: int,
    reach: np.ndarray | None,
    alone_too: bool,
    options: ResidualOptions,
) -> dict[str, Any]:
    """Check a candidate against the whole model: at its model joint first, then alone.

    A placement is confirmed when it lowers ``joint``'s held-out RMS by ``min_rms_gain`` and
    raises no explained joint's (:func:`_worse`) by more than that, and (``veto``: the same
    model on blocks held out by phase) raises no explained joint's phase-held-out RMS by more
    than that either: an effect that only fits the poses of a repeated trajectory fails there.
    The model joint (``reach``) is kept when it is confirmed; ``joint`` alone is tried after
    it when ``alone_too`` (or without a ``reach``). Returns ``confirmed``, ``reach`` (None: the
    joint alone) and the last placement's figures.
    """
    result: dict[str, Any] = {}
    placements: tuple[np.ndarray | None, ...] = (None,)
    if reach is not None:
        placements = (reach, None) if alone_too else (reach,)
    for placement in placements:
        placed = _placed(cols, joint, placement, len(before))
        after = check.relative_rms(placed)
        gain = 1.0 - after[joint] / max(before[joint], 1e-300)
        worse = _worse(before, after, options.min_rms_gain)
        if veto is not None:
            worse |= _worse(veto.relative_rms(), veto.relative_rms(placed), options.min_rms_gain)
        result = {
            "confirmed": bool(gain >= options.min_rms_gain and not worse.any()),
            "reach": placement,
            "gain": float(gain),
            "worse_joints": [int(k) + 1 for k in np.flatnonzero(worse)],
            "after": after.tolist(),
        }
        if result["confirmed"]:
            break
    return result


def _joint_check(
    data: _Data, friction_l: np.ndarray, offsets: bool, options: ResidualOptions, folds: np.ndarray
) -> _JointCheck:
    """Return the whole model's design at the selected rows: rigid body, friction, offsets.

    The friction is the stage-one model's (a wavelet network's coupled CV fallback): a
    velocity map does not extrapolate to blocks held out by phase.
    """
    n = friction_l.shape[1]
    rigid = np.concatenate(
        [p.signals.rigid_regressor[idx] for p, idx in zip(data.prepared, data.rows, strict=True)]
    )
    y = np.concatenate(
        [p.signals.tau_lowpassed_nm[idx] for p, idx in zip(data.prepared, data.rows, strict=True)]
    )
    parts = [rigid, friction_l[:, :, np.any(friction_l != 0.0, axis=(0, 1))]]
    if offsets:
        parts.append(np.broadcast_to(np.eye(n), (rigid.shape[0], n, n)))
    return _JointCheck(np.concatenate(parts, axis=2), y, folds, options.folds, options.ridge)


@dataclass(frozen=True, eq=False)
class _Data:
    """Stacked, decimated valid samples of all recordings."""

    prepared: list[PreparedRecording]
    rows: list[np.ndarray]
    folds: np.ndarray
    raw: dict[str, np.ndarray]
    loads: list[np.ndarray]
    cache: dict[BasisSpec, np.ndarray] = field(default_factory=dict)
    #: Folds by phase (None unless every recording is periodic, :func:`trajectory_period`).
    phase_folds: np.ndarray | None = None


def _select_rows(
    prepared: Sequence[PreparedRecording], options: ResidualOptions, base_values: np.ndarray
) -> _Data:
    rows, fold_ids, phase_ids = [], [], []
    t, q, qd, tau, loads = [], [], [], [], []
    for item in prepared:
        s = item.signals
        idx = np.flatnonzero(s.valid)[:: options.decimate]
        if idx.size < options.folds * 10:
            raise DataError("recording too short for held-out blocks", path=item.recording.source)
        rows.append(idx)
        n_blocks = options.folds * options.blocks_per_fold
        block = (np.arange(idx.size) * n_blocks) // idx.size
        fold_ids.append(block % options.folds)
        period = (
            trajectory_period(s.t_s[s.valid], s.q_rad[s.valid]) if options.phase_folds else None
        )
        if period is not None:
            phase = np.mod(s.t_s[idx] - s.t_s[idx[0]], period) / period
            phase_block = np.minimum((phase * n_blocks).astype(int), n_blocks - 1)
            phase_ids.append(phase_block % options.folds)
        t.append(s.t_s)
        q.append(s.q_rad)
        qd.append(s.qd_rad_s)
        load = np.einsum("kjp,p->kj", s.rigid_regressor, base_values)
        loads.append(load)
        tau.append(load)
    raw = {
        "t": np.concatenate(t),
        "q": np.concatenate(q),
        "qd": np.concatenate(qd),
        "tau": np.concatenate(tau),
    }
    phase_folds = np.concatenate(phase_ids) if len(phase_ids) == len(rows) else None
    return _Data(
        list(prepared), rows, np.concatenate(fold_ids), raw, loads, phase_folds=phase_folds
    )


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


def _filtered_columns(data: _Data, spec: BasisSpec) -> np.ndarray:
    """Low-pass filter the candidate's basis per recording, at the selected rows (cached)."""
    cached = data.cache.get(spec)
    if cached is not None:
        return cached
    out = []
    for item, idx, load in zip(data.prepared, data.rows, data.loads, strict=True):
        s = item.signals
        phi = spec.basis(s.t_s, s.q_rad, s.qd_rad_s, load)
        out.append(lowpass_batch(phi, s.t_s, s.config.cutoff_hz)[idx])
    columns = np.concatenate(out)
    data.cache[spec] = columns
    return columns


def _selected_friction_regressor(data: _Data, friction: FrictionModel) -> np.ndarray:
    """Return the filtered friction regressor at the selected rows, ``(rows, n, p_f)``."""
    return np.concatenate(
        [
            _friction_regressor(friction, item.signals)[idx]
            for item, idx in zip(data.prepared, data.rows, strict=True)
        ]
    )


def _joint_base(
    data: _Data,
    friction_l: np.ndarray,
    joint: int,
    offsets: bool,
    network: FrictionModel | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``joint``'s base design and filtered torque at the selected rows.

    Its friction columns are the parameters whose torque reaches the joint (``friction_l``:
    :func:`_selected_friction_regressor`): its own basis for per-joint friction, the laws
    reaching it through the coupling for friction in model coordinates.
    """
    own = friction_l[:, joint, :]
    rigid, rest, ys = [], [], []
    for item, idx in zip(data.prepared, data.rows, strict=True):
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


def _candidates(
    data: _Data,
    joint: int,
    n: int,
    residual: np.ndarray,
    options: ResidualOptions,
    has_offsets: bool,
    velocity_covered: tuple[int, ...] = (),
) -> list[BasisSpec]:
    """List candidate effects for one joint.

    ``velocity_covered``: velocities the friction already maps.
    """
    raw = data.raw
    specs: list[BasisSpec] = []
    names = [f"q{i + 1}" for i in range(n)] + [
        f"q{a + 1}-q{b + 1}" for a in range(n) for b in range(a + 1, n)
    ]
    selected = np.concatenate(
        [
            idx + offset
            for idx, offset in zip(
                data.rows,
                np.cumsum([0] + [p.signals.n_samples for p in data.prepared[:-1]]),
                strict=True,
            )
        ]
    )
    for name in names:
        x = variable_values(name, raw["t"], raw["q"], raw["qd"], raw["tau"])
        lo, hi = np.percentile(x, [0.5, 99.5])
        if hi - lo < 1e-3:
            continue
        for count in options.smooth_counts:
            specs.append(BasisSpec(joint, name, "smooth", "none", float(lo), float(hi), count))
        for count in options.modulated_counts:
            specs.append(BasisSpec(joint, name, "smooth", "sign", float(lo), float(hi), count))
            specs.append(BasisSpec(joint, name, "smooth", "both", float(lo), float(hi), count))
        frequency = _dominant_frequency(x[selected], residual, float(hi - lo))
        if frequency is not None:
            specs.append(
                BasisSpec(
                    joint,
                    name,
                    "periodic",
                    "none",
                    frequency=frequency,
                    harmonics=options.harmonics,
                )
            )
    for k in range(n):
        if k == joint or k in velocity_covered:
            continue
        x = raw["qd"][:, k]
        lo, hi = np.percentile(x, [0.5, 99.5])
        if hi - lo > 1e-3:
            specs.append(BasisSpec(joint, f"qd{k + 1}", "smooth", "none", float(lo), float(hi), 6))
    if not has_offsets:
        # The load is the rigid-body model torque (see teleop_force.identification.effects): robots
        # with a model.
        specs.append(BasisSpec(joint, f"tau{joint + 1}", "abs", "sign"))
    specs.append(BasisSpec(joint, "t", "linear", "none"))
    specs.append(BasisSpec(joint, "t", "linear", "sign"))
    if joint not in velocity_covered:
        specs.append(
            BasisSpec(joint, f"qd{joint + 1}", "stribeck", "sign", scales=(0.03, 0.1, 0.3))
        )
    if not has_offsets:
        specs.append(BasisSpec(joint, "t", "constant", "none"))
    specs.append(BasisSpec(joint, "t", "constant", "positive"))
    return specs


#: Displacements since the last reversal [rad] at which the reversal stand-ins decay.
REVERSAL_DISPLACEMENTS_RAD: tuple[float, ...] = (0.003, 0.01, 0.03, 0.1)
#: Times since the last reversal [s] at which the reversal stand-ins decay.
REVERSAL_TIMES_S: tuple[float, ...] = (0.02, 0.05, 0.15, 0.4)
#: A joint's direction of motion changes when its velocity passes this far beyond zero [rad/s].
REVERSAL_DEAD_BAND_RAD_S = 0.005


def reversal_transient_basis(
    t_s: np.ndarray, q_rad: np.ndarray, qd_rad_s: np.ndarray
) -> np.ndarray:
    """Friction-shaped transients after each motion reversal of one joint: (N,) -> (N, 16).

    The direction of motion is the sign of ``qd_rad_s`` held through the dead band
    (:data:`REVERSAL_DEAD_BAND_RAD_S`); it changes at a reversal. Columns: ``exp(-|q - q_r| / x)``
    for each displacement scale ``x`` and ``exp(-(t - t_r) / T)`` for each time scale ``T``
    (``q_r``, ``t_r``: angle and time of the last reversal), each times the smoothed direction
    ``tanh(qd / dead band)`` and alone. Every column is 1 (or +-1) at a reversal and decays
    as the joint moves away from it: presliding and a velocity estimate that lags the true
    velocity where dry friction flips.
    """
    t_s = np.asarray(t_s, dtype=float)
    q_rad = np.asarray(q_rad, dtype=float)
    v = np.asarray(qd_rad_s, dtype=float)
    index = np.arange(v.size)
    band = REVERSAL_DEAD_BAND_RAD_S
    moving = np.where(v > band, 1.0, np.where(v < -band, -1.0, 0.0))
    direction = moving[np.maximum.accumulate(np.where(moving != 0.0, index, 0))]
    changed = np.r_[True, direction[1:] != direction[:-1]] if v.size else np.zeros(0, dtype=bool)
    last = np.maximum.accumulate(np.where(changed, index, 0))
    moved = np.abs(q_rad - q_rad[last])[:, None] / np.asarray(REVERSAL_DISPLACEMENTS_RAD)
    waited = (t_s - t_s[last])[:, None] / np.asarray(REVERSAL_TIMES_S)
    decay = np.concatenate((np.exp(-moved), np.exp(-waited)), axis=1)
    sign = np.tanh(v / REVERSAL_DEAD_BAND_RAD_S)[:, None]
    return np.concatenate((decay * sign, decay), axis=1)


def _velocity_controls(data: _Data, joint: int, covered: tuple[int, ...]) -> list[BasisSpec]:
    """Friction-shaped stand-ins for what the friction model may still miss on ``joint``.

    Velocities the wavelet network maps are not offered as effects; these shapes of them
    (smooth in each covered velocity, alone and times ``sgn(qd_joint)``, and low-speed
    Stribeck terms) only serve as a control: a candidate on another variable must still
    lower the held-out error with them in the model, so that friction the network has not
    learnt is not named after a variable that merely correlates with the velocities (on a
    periodic trajectory, every variable does).
    """
    specs = []
    for k in covered:
        x = data.raw["qd"][:, k]
        lo, hi = np.percentile(x, [0.5, 99.5])
        if hi - lo < 1e-3:
            continue
        specs.append(BasisSpec(joint, f"qd{k + 1}", "smooth", "none", float(lo), float(hi), 8))
        specs.append(BasisSpec(joint, f"qd{k + 1}", "smooth", "sign", float(lo), float(hi), 8))
    if joint in covered:
        specs.append(
            BasisSpec(joint, f"qd{joint + 1}", "stribeck", "sign", scales=(0.03, 0.1, 0.3))
        )
    return specs


def _dominant_frequency(x: np.ndarray, residual: np.ndarray, span: float) -> float | None:
    """Spatial frequency of the strongest periodic component of ``residual`` over ``x``."""
    if span <= 0:
        return None
    low = 2.0 * np.pi * 2.0 / span
    grid = np.linspace(max(low, 2.0), 120.0, 600)
    if grid.size == 0:
        return None
    r = residual - residual.mean()
    phase = np.outer(x, grid)
    power = (r @ np.cos(phase)) ** 2 + (r @ np.sin(phase)) ** 2
    return float(grid[int(np.argmax(power))])


def effect_reaches(description: RobotDescription) -> list[np.ndarray | None]:
    """Per motor ``j``, the reach of a torque at model joint ``j``: row ``j`` of the coupling.

    Scaled so the weight on motor ``j`` is 1; None where that torque lands on motor ``j`` alone
    (or the coupling has no row ``j`` with a weight on it).
    """
    coupling = description.coupling
    out: list[np.ndarray | None] = []
    for j in range(description.n_joints):
        if j >= coupling.shape[0] or coupling[j, j] == 0.0:
            out.append(None)
            continue
        row = coupling[j] / coupling[j, j]
        out.append(row if np.count_nonzero(row) > 1 else None)
    return out


def trace_residual(
    recordings: Sequence[Recording],
    description: RobotDescription,
    options: ResidualOptions | None = None,
    config: FilterConfig | None = None,
) -> ResidualReport:
    """Fit, find what the model lacks on held-out data, add it, refit, report before and after."""
    options = options or ResidualOptions()
    config = config or FilterConfig()
    prepared, base = prepare(recordings, description, config)
    n = description.n_joints
    offsets = not description.has_rigid_body if options.offsets is None else options.offsets
    friction = stage_one_friction(options.friction, description)
    stage_one = _stage_one_fit(prepared, base, friction, offsets)
    data = _select_rows(prepared, options, stage_one[: 0 if base is None else base.count])
    network = None
    if options.friction == "wn":
        network = _baseline_network(prepared, description, base, friction, offsets, stage_one)
    designs = []
    friction_l = _selected_friction_regressor(data, friction)
    for j in range(n):
        columns, y = _joint_base(data, friction_l, j, offsets, network)
        designs.append(_Design(columns, y, data.folds, options.folds, options.ridge))
    # The velocities the friction maps beyond each joint's own: the network's inputs, or the
    # model-coordinate laws that reach the joint through the coupling.
    maps_inputs = network is not None or not friction.block_diagonal
    covered = description.friction_inputs if maps_inputs else tuple(() for _ in range(n))
    controls: list[_Design | None] = []
    for j, design in enumerate(designs):
        specs = _velocity_controls(data, j, covered[j])
        if not specs:
            controls.append(None)
            continue
        extra = np.concatenate(
            [_filtered_columns(data, spec) for spec in specs]
            + [_friction_stand_in_columns(data, j, description)],
            axis=1,
        )
        controls.append(
            _Design(
                np.concatenate((design.base, extra), axis=1),
                design.y,
                data.folds,
                options.folds,
                options.ridge,
            )
        )
    placement = options.effect_placement
    if placement == "auto":
        placement = "either" if options.friction == ModelCoordinateFriction.kind else "motor"
    reaches = effect_reaches(description) if placement != "motor" else [None] * n
    before = np.array([d.relative_rms(d.held_out_errors()) for d in designs])
    current = before.copy()
    accepted: list[TracedEffect] = []
    history: list[dict[str, Any]] = []
    rejected: list[dict[str, Any]] = []
    plots: list[dict[str, Any]] = []
    check = _joint_check(data, friction_l, offsets, options, data.folds)
    veto = (
        None
        if data.phase_folds is None
        else _joint_check(data, friction_l, offsets, options, data.phase_folds)
    )
    refuted: set[tuple[int, BasisSpec]] = set()
    for _ in range(options.max_effects):
        passing: list[tuple[float, int, BasisSpec, np.ndarray, np.ndarray, float]] = []
        for j, design in enumerate(designs):
            base_errors = design.held_out_errors()
            theta = np.linalg.lstsq(design.base, design.y, rcond=None)[0]
            residual = design.y - design.base @ theta
            for spec in _candidates(data, j, n, residual, options, offsets, covered[j]):
                if (j, spec) in refuted:
                    continue
                cols = _filtered_columns(data, spec)
                if not np.all(np.isfinite(cols)):
                    continue
                errors = design.held_out_errors(cols)
                gain = 1.0 - np.sqrt(errors.sum() / max(base_errors.sum(), 1e-300))
                wins = float(np.mean(errors < base_errors))
                if gain >= options.min_rms_gain and wins >= options.min_fold_wins:
                    control_gain = _control_gain(controls[j], cols)
                    if control_gain < options.min_control_gain:
                        rejected.append(
                            {
                                "effect": spec.describe(),
                                "gain": float(gain),
                                "control_gain": control_gain,
                            }
                        )
                        continue
                    passing.append((gain, j, spec, cols, errors, control_gain))
        best = None
        passing.sort(key=lambda entry: -entry[0])
        whole_before = check.relative_rms()
        for entry in passing[: options.confirm_candidates]:
            _, j, spec, cols, _, _ = entry
            checked = _confirm(
                check, veto, whole_before, cols, j, reaches[j], placement == "either", options
            )
            if checked["confirmed"]:
                best = entry
                reach = checked["reach"]
                break
            refuted.add((j, spec))
            rejected.append(
                {
                    "effect": spec.describe(),
                    "gain": float(entry[0]),
                    "whole_model_gain": checked["gain"],
                    "whole_model_worse_joints": checked["worse_joints"],
                    "whole_model_before": whole_before.tolist(),
                    "whole_model_after": checked["after"],
                }
            )
        if best is None:
            break
        gain, j, spec, cols, errors, control_gain = best
        placed = _placed(cols, j, reach, n)
        check.add(placed)
        if veto is not None:
            veto.add(placed)
        design = designs[j]
        base_errors = design.held_out_errors()
        explained = 1.0 - errors.sum() / max(base_errors.sum(), 1e-300)
        after_j = design.relative_rms(errors)
        accepted.append(
            TracedEffect(
                spec,
                float(explained),
                float(current[j]),
                after_j,
                None if reach is None else tuple(float(w) for w in reach),
            )
        )
        history.append(
            {
                "effect": spec.describe(),
                "kind": spec.kind,
                "gain": float(gain),
                "control_gain": control_gain,
            }
        )
        plots.append(_plot_data(data, design, spec, cols))
        # The effect's share on the other joints it reaches is part of their models from now
        # on (free columns of each joint's design, as every column there is).
        for k in (j,) if reach is None else np.flatnonzero(reach):
            designs[k].add(cols)
            control = controls[k]
            if control is not None:
                control.add(cols)
        current[j] = after_j
    model = _final_model(
        prepared,
        description,
        base,
        friction,
        config,
        offsets,
        accepted,
        stage_one[: 0 if base is None else base.count],
    )
    if network is not None:
        model = _with_network(model, prepared, description)
    return ResidualReport(
        before,
        current,
        tuple(accepted),
        model,
        int(data.folds.size),
        tuple(history),
        {"effects": plots},
        tuple(rejected),
    )


def _friction_stand_in_columns(
    data: _Data, joint: int, description: RobotDescription
) -> np.ndarray:
    """Return ``joint``'s filtered friction stand-ins at the selected rows.

    The rigid-body fit's nuisance friction terms (coupled inputs too), then the transients
    after the joint's motion reversals (:func:`reversal_transient_basis`).
    """
    out = []
    for item, idx in zip(data.prepared, data.rows, strict=True):
        s = item.signals
        nuisance, _ = nuisance_friction_basis(
            s.qd_rad_s, joint, description.friction_inputs, RigidBodyFitOptions()
        )
        reversal = reversal_transient_basis(s.t_s, s.q_rad[:, joint], s.qd_rad_s[:, joint])
        phi = np.concatenate((nuisance, reversal), axis=1)
        out.append(lowpass_batch(phi, s.t_s, s.config.cutoff_hz)[idx])
    return np.concatenate(out)


def _control_gain(control: _Design | None, cols: np.ndarray) -> float:
    """Held-out RMS gain of ``cols`` over the design with the friction controls (1 without)."""
    if control is None:
        return 1.0
    base_errors = control.held_out_errors()
    errors = control.held_out_errors(cols)
    return float(1.0 - np.sqrt(errors.sum() / max(base_errors.sum(), 1e-300)))


def _stage_one_fit(prepared, base, friction, offsets) -> np.ndarray:
    """Parameters of the stage-one fit (rigid body, CV friction, offsets) on all data."""
    from teleop_force.identification.pipeline import _stack_regressor

    regressor, torque = _stack_regressor(prepared, friction, offsets)
    return least_squares(regressor, torque, [f"p{i}" for i in range(regressor.shape[2])]).parameters


def _baseline_network(prepared, description, base, friction, offsets, theta):
    """Return the batch-fitted wavelet network of the model the residual is taken from."""
    from teleop_force.identification.pipeline import WaveletOptions
    from teleop_force.identification.wavelet_training import train_wavelet_network

    r = 0 if base is None else base.count
    p_f = int(sum(friction.parameter_counts()))
    fallback = CoupledCoulombViscous(description.n_joints, description.friction_inputs)
    if isinstance(friction, CoupledCoulombViscous):
        fallback.parameters = theta[r : r + p_f].copy()
    offsets_nm = theta[r + p_f :] if offsets else np.zeros(description.n_joints)
    network, _ = train_wavelet_network(
        prepared, description, theta[:r], offsets_nm, fallback, WaveletOptions("batch")
    )
    return network


def _with_network(
    model: DynamicModel, prepared: Sequence[PreparedRecording], description: RobotDescription
) -> DynamicModel:
    """Retrain the wavelet network on what the rigid body, offsets and effects leave."""
    from teleop_force.identification.pipeline import WaveletOptions
    from teleop_force.identification.wavelet_training import train_wavelet_network

    known = []
    for item in prepared:
        s = item.signals
        load = np.einsum("kjp,p->kj", s.rigid_regressor, model.base_values)
        effects = model.effects_torque(s.t_s, s.q_rad, s.qd_rad_s, load)
        known.append(lowpass_batch(effects, s.t_s, s.config.cutoff_hz))
    fallback = model.friction
    if not isinstance(fallback, CoupledCoulombViscous):
        return model
    network, _ = train_wavelet_network(
        prepared,
        description,
        model.base_values,
        model.offsets_nm,
        fallback,
        WaveletOptions("batch"),
        known_torque_l=known,
    )
    return replace(model, friction=network)


def _plot_data(data: _Data, design: _Design, spec: BasisSpec, cols: np.ndarray) -> dict[str, Any]:
    """Residual of the joint against the traced variable, before and after adding ``spec``."""
    raw = data.raw
    offsets = np.cumsum([0] + [p.signals.n_samples for p in data.prepared[:-1]])
    selected = np.concatenate([idx + o for idx, o in zip(data.rows, offsets, strict=True)])
    variable = spec.variable if spec.shape != "constant" else "t"
    x = variable_values(variable, raw["t"], raw["q"], raw["qd"], raw["tau"])[selected]
    theta = np.linalg.lstsq(design.base, design.y, rcond=None)[0]
    before = design.y - design.base @ theta
    both = np.concatenate((design.base, cols), axis=1)
    theta2 = np.linalg.lstsq(both, design.y, rcond=None)[0]
    after = design.y - both @ theta2
    return {"spec": spec, "x": x, "before": before, "after": after}


def _final_model(
    prepared, description, base, friction, config, offsets, accepted, load_values
) -> DynamicModel:
    """Refit rigid body, friction and all effects together on all data.

    The effects' load variable is the rigid-body torque of ``load_values`` (stage one); the
    saved model evaluates it with its own, refitted, rigid body (nearly the same).
    """
    n = description.n_joints
    counts = friction.parameter_counts()
    p_f = int(sum(counts))
    r = 0 if base is None else base.count
    specs = [e.spec for e in accepted]
    effect_sizes = [s.size for s in specs]
    total = r + p_f + (n if offsets else 0) + int(sum(effect_sizes))
    blocks, torques = [], []
    for item in prepared:
        s = item.signals
        v = s.valid
        m = int(v.sum())
        a = np.zeros((m, n, total))
        a[:, :, :r] = s.rigid_regressor[v]
        a[:, :, r : r + p_f] = _friction_regressor(friction, s)[v]
        col = r + p_f
        if offsets:
            a[:, :, col : col + n] = np.eye(n)
            col += n
        load = np.einsum("kjp,p->kj", s.rigid_regressor, load_values)
        for spec, traced in zip(specs, accepted, strict=True):
            phi = lowpass_batch(
                spec.basis(s.t_s, s.q_rad, s.qd_rad_s, load), s.t_s, config.cutoff_hz
            )[v]
            reach = None if traced.reach is None else np.asarray(traced.reach)
            a[:, :, col : col + spec.size] = _placed(phi, spec.joint, reach, n)
            col += spec.size
        blocks.append(a)
        torques.append(s.tau_lowpassed_nm[v])
    names = list(base.names() if base is not None else [])
    names += friction.all_parameter_names()
    if offsets:
        names += [f"offset_{j + 1}" for j in range(n)]
    for k, spec in enumerate(specs):
        names += [f"effect{k + 1}[{i}]" for i in range(spec.size)]
    fit = least_squares(np.concatenate(blocks), np.concatenate(torques), names, ridge=1e-8)
    theta = fit.parameters
    friction.parameters = theta[r : r + p_f].copy()
    col = r + p_f
    offsets_nm = np.zeros(n)
    if offsets:
        offsets_nm = theta[col : col + n].copy()
        col += n
    effects = []
    for spec, traced in zip(specs, accepted, strict=True):
        effects.append(
            FoundEffect(
                spec,
                theta[col : col + spec.size],
                traced.explained,
                None if traced.reach is None else np.asarray(traced.reach),
            )
        )
        col += spec.size
    return DynamicModel(
        robot=description.name,
        n_joints=n,
        filter_config=config,
        base=base,
        base_values=theta[:r],
        base_std=fit.standard_deviations[:r],
        friction=friction,
        offsets_nm=offsets_nm,
        effects=tuple(effects),
        notes={"sources": [str(p.recording.source) for p in prepared], "residual_loop": True},
    )
