"""Guards by construction around identification: a failed fit is caught, the WN earns its joints.

:func:`identify_guarded` sees only the recordings it is given, and splits each in time: the
first part (``1 - held_out_fraction``) to fit, the rest to check (the *inner split*). On the
check part:

- **a failed fit is caught**: a model whose relative RMS on any joint exceeds 1 (worse than
  predicting zero) or is not finite, or whose fit raised, is reported with its cause
  (:class:`FitFailure`) and the next simpler friction is tried (:data:`SIMPLER`:
  ``wn -> coupled-cv -> cv``, ``model-cv -> cv``). If none passes, the simplest is kept
  and :attr:`GuardReport.failed` says why (``strict``: :class:`ModelError` instead): a
  figure from it counts as a failure.
- **the WN earns its joints**: with the default structure (the network added to the coupled
  CV), joint ``j`` keeps its network only if the model's check error on ``j`` is below the
  same model's with the network zeroed (its coupled CV); elsewhere the network is zeroed, so
  the joint's friction is exactly the coupled CV. With the network alone (``--wn-structure
  alone``) a joint that loses sends the whole model to the coupled CV.

The reported model is then fitted on all the recordings with the friction and WN joints the
check chose; :attr:`GuardReport` says what was tried and why (``FitReport.details["guards"]``).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError, DataError, ModelError
from teleop_force.friction.kinds import FrictionKind
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.pipeline import FitReport, evaluate_model, identify_model
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.description import RobotDescription

#: The next simpler friction of each kind (None: there is none).
SIMPLER: dict[FrictionKind, FrictionKind | None] = {
    FrictionKind.WN: FrictionKind.COUPLED_CV,
    FrictionKind.COUPLED_CV: FrictionKind.CV,
    FrictionKind.MODEL_CV: FrictionKind.CV,
    FrictionKind.CV: None,
}
#: Share of each recording, at its end, that the guards check on.
HELD_OUT_FRACTION = 0.25


@dataclass(frozen=True)
class FitFailure:
    """A fit the guards refused: its friction kind and why."""

    friction: str
    cause: str

    def to_dict(self) -> dict[str, str]:
        """Return the failure as JSON-ready values."""
        return {"friction": self.friction, "cause": self.cause}


@dataclass(frozen=True)
class GuardReport:
    """What the guards tried on the inner split and what they chose.

    Attributes:
        requested: The friction asked for.
        chosen: The friction of the reported model.
        fallbacks: Every refused fit, in order.
        check_relative_rms: Per friction tried, its check relative RMS per joint.
        wn_joints: Per joint, whether the network is kept (None: no network chosen).
        cv_relative_rms: The WN model's check error with the network zeroed (None: no WN).

    """

    requested: str
    chosen: str
    fallbacks: tuple[FitFailure, ...]
    check_relative_rms: dict[str, tuple[float, ...]]
    wn_joints: tuple[bool, ...] | None = None
    cv_relative_rms: tuple[float, ...] | None = None
    failed: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the report as JSON-ready values."""
        return {
            "requested": self.requested,
            "chosen": self.chosen,
            "fallbacks": [f.to_dict() for f in self.fallbacks],
            "check_relative_rms": {k: list(v) for k, v in self.check_relative_rms.items()},
            "wn_joints": None if self.wn_joints is None else list(self.wn_joints),
            "cv_relative_rms": None if self.cv_relative_rms is None else list(self.cv_relative_rms),
            "failed": self.failed,
        }

    def lines(self) -> list[str]:
        """Return one line per fallback and one for the WN's joints (what ``identify`` logs)."""
        out = [f"fallback: {f.friction} refused ({f.cause})" for f in self.fallbacks]
        if self.failed is not None:
            out.append(f"warning: every friction failed the held-out check, kept {self.chosen}")
        if self.wn_joints is not None:
            kept = [j + 1 for j, keep in enumerate(self.wn_joints) if keep]
            out.append(
                "wavelet network kept on joints "
                + (", ".join(str(j) for j in kept) if kept else "none")
                + " (elsewhere the coupled CV, which did better on the check split)"
            )
        return out


def split_in_time(recording: Recording, held_out_fraction: float) -> tuple[Recording, Recording]:
    """Return the first ``1 - held_out_fraction`` of ``recording`` and the rest."""
    if not 0.0 < held_out_fraction < 1.0:
        raise ConfigurationError(f"held_out_fraction must be in (0, 1), got {held_out_fraction}")
    n = recording.t_s.shape[0]
    k = round((1.0 - held_out_fraction) * n)
    if k < 2 or n - k < 2:
        raise DataError(f"{n} samples are too few to split", path=recording.source)

    def part(rows: slice) -> Recording:
        force = recording.f_tip_in_base_n
        return Recording(
            recording.t_s[rows],
            recording.q_rad[rows],
            recording.tau_nm[rows],
            None if force is None else force[rows],
            recording.source,
        )

    return part(slice(0, k)), part(slice(k, n))


def fit_failure(relative_rms: np.ndarray) -> str | None:
    """Return why check errors ``relative_rms`` (per joint) mean a failed fit, or None."""
    causes = []
    for j, value in enumerate(np.asarray(relative_rms, dtype=float)):
        if not np.isfinite(value):
            causes.append(f"joint {j + 1}: check error not finite")
        elif value > 1.0:
            causes.append(
                f"joint {j + 1}: check relative RMS {100 * value:.1f} % > 100 %"
                " (worse than predicting zero)"
            )
    return "; ".join(causes) if causes else None


def zero_network_joints(model: DynamicModel, joints: Sequence[int]) -> None:
    """Zero the network's coefficients of ``joints`` (in place): their friction is the CV's."""
    network = model.friction
    if not isinstance(network, WaveletNetwork):
        raise ConfigurationError("only a wavelet network has joints to zero")
    for j in joints:
        network.set_joint_parameters(j, np.zeros(network.parameter_counts()[j]))


def _kwargs_for(kind: FrictionKind, kwargs: dict[str, Any]) -> dict[str, Any]:
    if kind is FrictionKind.MODEL_CV:
        return {**kwargs, "sticking": False}
    if kind is not FrictionKind.WN:
        return {key: value for key, value in kwargs.items() if key != "wavelet"}
    return kwargs


def _coupled_cv_check(
    inner: DynamicModel,
    fit_parts: Sequence[Recording],
    check_parts: Sequence[Recording],
    description: RobotDescription,
    options: dict[str, Any],
) -> tuple[float, ...]:
    """Return the coupled CV's check error per joint.

    The WN model's with the network zeroed (it adds to the CV), or a coupled CV fitted on the
    fit parts (the network alone blends with its CV).
    """
    network = inner.friction
    if isinstance(network, WaveletNetwork) and network.on_fallback:
        as_cv = copy.deepcopy(inner)
        zero_network_joints(as_cv, range(description.n_joints))
    else:
        kind = FrictionKind.COUPLED_CV
        as_cv, _ = identify_model(list(fit_parts), description, kind, **_kwargs_for(kind, options))
    rms = evaluate_model(as_cv, list(check_parts))["relative_rms"]
    return tuple(float(x) for x in rms)


def identify_guarded(
    recordings: Sequence[Recording],
    description: RobotDescription,
    friction_kind: FrictionKind | str = FrictionKind.WN,
    *,
    held_out_fraction: float = HELD_OUT_FRACTION,
    strict: bool = False,
    **identify_options: Any,
) -> tuple[DynamicModel, FitReport, GuardReport]:
    """Identify as :func:`identify_model` does, behind the guards (module docstring).

    ``identify_options`` go to :func:`identify_model` (``wavelet``, ``offsets``,
    ``sticking``, ``count_observer``...).

    Raises:
        ModelError: with ``strict``, when every friction down to the simplest fails the
            check (else the simplest is kept, :attr:`GuardReport.failed` set); without it,
            when the simplest's fit raises.

    """
    requested = FrictionKind.parse(friction_kind)
    fit_parts, check_parts = zip(
        *(split_in_time(r, held_out_fraction) for r in recordings), strict=True
    )
    fallbacks: list[FitFailure] = []
    checks: dict[str, tuple[float, ...]] = {}
    kind: FrictionKind = requested
    inner: DynamicModel | None = None
    failed: str | None = None
    while True:
        options = _kwargs_for(kind, identify_options)
        try:
            inner, _ = identify_model(list(fit_parts), description, kind, **options)
            rms = np.asarray(evaluate_model(inner, list(check_parts))["relative_rms"])
        except (ModelError, DataError, np.linalg.LinAlgError) as error:
            inner = None
            cause: str | None = f"the fit raised: {error}"
        else:
            checks[kind.value] = tuple(float(x) for x in rms)
            cause = fit_failure(rms)
        if cause is None:
            break
        fallbacks.append(FitFailure(kind.value, cause))
        simpler = SIMPLER[kind]
        if simpler is None:
            failed = "; ".join(f"{f.friction}: {f.cause}" for f in fallbacks)
            if strict or inner is None:
                raise ModelError(f"every friction failed the held-out check: {failed}")
            break
        kind = simpler
    if inner is None:  # pragma: no cover - the loop above leaves with a model or raises
        raise ModelError("no model")
    wn_joints: tuple[bool, ...] | None = None
    cv_rms: tuple[float, ...] | None = None
    if kind is FrictionKind.WN and isinstance(inner.friction, WaveletNetwork):
        cv_rms = _coupled_cv_check(inner, fit_parts, check_parts, description, identify_options)
        keep = tuple(bool(w < c) for w, c in zip(checks[kind.value], cv_rms, strict=True))
        if not inner.friction.on_fallback and not all(keep):
            cause = "a joint's network lost to the coupled CV on the check split"
            fallbacks.append(FitFailure(kind.value, cause))
            kind = FrictionKind.COUPLED_CV
            checks[kind.value] = cv_rms
        else:
            wn_joints = keep
    model, report = identify_model(
        recordings, description, kind, **_kwargs_for(kind, identify_options)
    )
    if wn_joints is not None and not all(wn_joints):
        zero_network_joints(model, [j for j, keep in enumerate(wn_joints) if not keep])
        training = evaluate_model(model, recordings)["relative_rms"]
        report = dataclasses.replace(report, friction_relative_rms=training)
    guards = GuardReport(
        requested.value, kind.value, tuple(fallbacks), checks, wn_joints, cv_rms, failed
    )
    report.details["guards"] = guards.to_dict()
    return model, report, guards
