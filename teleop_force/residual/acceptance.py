"""A held-out test of every effect the loop accepts, with the family-wise error controlled.

:func:`trace_residual_tested` splits each recording in time before anything is fitted: the
loop (:func:`~teleop_force.residual.loop.trace_residual`) searches the first part
(``1 - test_fraction``), and each effect it accepts is then tested on the last part, which
neither the search nor the effect's coefficients saw:

- the search's model with and without the effect (the same coefficients otherwise) predicts
  the effect's joint on the test part; the valid samples are cut into :data:`TEST_BLOCKS`
  contiguous blocks and ``d_b`` is the drop of the squared error in block ``b``;
- a one-sided sign-flip test of ``sum d_b`` (all ``2^B`` sign patterns, exact): an effect
  that does not predict the test part has ``d_b`` symmetric about a value ``<= 0``, so its
  p-value is at most uniform;
- the effect is kept if ``p <= level / max_effects`` (Bonferroni over every effect the
  search can send: the family-wise rate of false acceptance per session is at most
  ``level``, 0.01 by default).

This bounds the acceptances the noise makes by chance, by construction; it does not make a
wrongly shaped baseline right (an effect that really predicts what the baseline's friction
misses passes, as it should: the loop's friction controls name it as friction or refuse it).

The kept effects are refitted on all the data (the loop's final fit); the report's
``test_before``/``test_after`` are the test part's relative RMS per joint of the search's
baseline and of the search's model with the kept effects: held out.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from itertools import product
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.friction.kinds import FrictionKind
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.guards import split_in_time
from teleop_force.identification.prepared import prepare
from teleop_force.io.interchange_csv import Recording
from teleop_force.residual.loop import traced_with_baseline
from teleop_force.residual.model_fits import final_model, fit_baseline, fitted_model
from teleop_force.residual.options import ResidualOptions
from teleop_force.residual.report import ResidualReport
from teleop_force.robots.description import RobotDescription

#: Family-wise false-acceptance rate per session.
DEFAULT_LEVEL = 0.01
#: Share of each recording, at its end, the effects are tested on.
TEST_FRACTION = 1.0 / 3.0
#: Contiguous blocks of the test part (2^16 sign patterns: p-values down to 1.5e-5).
TEST_BLOCKS = 16

_SIGNS = np.array(list(product((1.0, -1.0), repeat=TEST_BLOCKS)))


def sign_flip_p_value(drops: np.ndarray) -> float:
    """One-sided exact sign-flip p-value of ``sum(drops) > 0`` (:data:`TEST_BLOCKS` values)."""
    d = np.asarray(drops, dtype=float)
    if d.shape != (TEST_BLOCKS,) or not np.all(np.isfinite(d)):
        return 1.0
    observed = d.sum()
    totals = _SIGNS @ d
    return float(np.mean(totals >= observed - 1e-12 * np.abs(d).sum()))


def _errors(
    model: DynamicModel, recordings: Sequence[Recording], description: RobotDescription
) -> tuple[np.ndarray, np.ndarray]:
    """Measured minus predicted filtered torque at the valid samples, and the measured."""
    prepared, _ = prepare(recordings, description, model.filter_config, model.base)
    errors, measured = [], []
    for item in prepared:
        s = item.signals
        tau_hat = model.predict_filtered_torque(s, item.recording.tau_nm)
        measured.append(s.tau_lowpassed_nm[s.valid])
        errors.append(s.tau_lowpassed_nm[s.valid] - tau_hat[s.valid])
    return np.concatenate(errors), np.concatenate(measured)


def _relative_rms(errors: np.ndarray, measured: np.ndarray) -> np.ndarray:
    energy = np.clip(np.sum(measured**2, axis=0), 1e-300, None)
    return np.asarray(np.sqrt(np.sum(errors**2, axis=0) / energy))


def _block_drops(without: np.ndarray, with_effect: np.ndarray) -> np.ndarray:
    blocks = np.array_split(np.arange(without.size), TEST_BLOCKS)
    return np.array([float(np.sum(without[b] ** 2 - with_effect[b] ** 2)) for b in blocks])


def trace_residual_tested(
    recordings: Sequence[Recording],
    description: RobotDescription,
    options: ResidualOptions | None = None,
    config: FilterConfig | None = None,
    *,
    level: float = DEFAULT_LEVEL,
    test_fraction: float = TEST_FRACTION,
) -> ResidualReport:
    """Run the residual loop and test every accepted effect held out (module docstring)."""
    if not 0.0 < level < 1.0:
        raise ConfigurationError(f"level must be in (0, 1), got {level}")
    options = (options or ResidualOptions()).for_robot(description.name, description.has_rigid_body)
    config = config or FilterConfig()
    search_parts, test_parts = zip(
        *(split_in_time(r, test_fraction) for r in recordings), strict=True
    )
    report, baseline = traced_with_baseline(list(search_parts), description, options, config)
    searched = report.model
    per_test = level / options.max_effects
    tested: list[dict[str, Any]] = []
    kept = []
    errors_all, _ = _errors(searched, test_parts, description)
    for i, traced in enumerate(report.effects):
        j = traced.spec.joint
        others = searched.effects[:i] + searched.effects[i + 1 :]
        without = dataclasses.replace(searched, effects=others)
        errors_without, _ = _errors(without, test_parts, description)
        p = sign_flip_p_value(_block_drops(errors_without[:, j], errors_all[:, j]))
        accepted = p <= per_test
        tested.append(
            {
                "effect": traced.spec.describe(),
                "joint": j + 1,
                "p_value": p,
                "level": per_test,
                "accepted": accepted,
            }
        )
        if accepted:
            kept.append(traced)
    kind = report.friction
    before_model = final_model(baseline, description, config, [], options.ridge, baseline.network)
    after_model = searched
    if len(kept) < len(report.effects):
        after_model = fitted_model(baseline, description, config, kept, options.ridge)
    test_before = _relative_rms(*_errors(before_model, test_parts, description))
    test_after = _relative_rms(*_errors(after_model, test_parts, description))
    whole = fit_baseline(
        recordings,
        description,
        FrictionKind(kind) if kind is not None else FrictionKind.WN,
        bool(options.offsets),
        config,
    )
    model = fitted_model(whole, description, config, kept, options.ridge)
    after = np.array(report.before, dtype=float)
    for traced in kept:
        after[traced.spec.joint] = traced.joint_rms_after
    return dataclasses.replace(
        report,
        after=after,
        effects=tuple(kept),
        model=model,
        tested=tuple(tested),
        test_before=test_before,
        test_after=test_after,
    )
