"""A payload as an effect: a change of the last link's inertial parameters.

A model in hand knows the robot's rigid body; a new tool or a held mass changes the last
link's ten inertial parameters (mass, first moments, inertia), and with them the torque on
every joint the link's motion loads, through the same rigid-body regressor. Only their
projection on the identified base parameters can show in the torque: the candidate is that
projection (an orthonormal basis of the base-parameter changes the last link's parameters
can make), so the extended model is the same model with other base values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop_force.identification.regressor import BaseParameters
from teleop_force.residual.options import ResidualOptions
from teleop_force.residual.samples import SelectedSamples
from teleop_force.residual.scoring import WholeModelCheck, worse_joints
from teleop_force.robots.description import RobotDescription

#: Parameters per link (mass, first moments, inertia) in the full parameter vector.
LINK_PARAMETERS = 10
#: A joint is reached when the payload's columns carry this share of the largest joint's.
REACH_SHARE = 1e-6


@dataclass(frozen=True, eq=False)
class PayloadCandidate:
    """The last link's inertial parameters as a candidate effect."""

    #: Base-parameter change per unit coefficient, ``(r, k)`` (orthonormal columns).
    directions: np.ndarray
    #: Filtered torque columns at the selected rows, ``(rows, n, k)``.
    columns: np.ndarray
    #: Joints (0-based) whose torque the payload changes.
    reached: tuple[int, ...]
    #: The angles its torque depends on (``q1``...).
    depends_on: tuple[str, ...]
    #: The link that holds it (1-based, as in the model's parameter names).
    link: int


@dataclass(frozen=True)
class PayloadConfirmation:
    """Outcome of checking the payload against the whole model (:func:`confirm_payload`)."""

    confirmed: bool
    #: The joint it helps most (0-based) and its gain there, on held-out blocks.
    joint: int
    gain: float
    #: The same joint's gain on the data it was not fitted on (None: no such data).
    holdout_gain: float | None
    worse_joints: tuple[int, ...]
    after: tuple[float, ...]


def payload_directions(
    base: BaseParameters | None, description: RobotDescription
) -> np.ndarray | None:
    """Return an orthonormal basis ``(r, k)`` of the base-parameter changes of the last link.

    The span of the base parameters' projection of the last link's ten inertial parameters
    (None without a body, or when none of them reaches the base parameters).
    """
    if base is None or not description.has_rigid_body or description.n_links < 1:
        return None
    n_full = base.independent.size + base.dependent.size
    first = LINK_PARAMETERS * (payload_link(description) - 1)
    projection = np.stack(
        [base.project(np.eye(n_full)[first + k]) for k in range(LINK_PARAMETERS)], axis=1
    )
    u, singular, _ = np.linalg.svd(projection, full_matrices=False)
    keep = singular > 1e-9 * max(float(singular.max(initial=0.0)), 1e-300)
    return u[:, keep] if keep.any() else None


def payload_link(description: RobotDescription) -> int:
    """Return the link (1-based) a payload is held by: the tip frame's, else the last.

    On a closed chain the last body of the model may be a parallelogram link (the dVRK
    MTM's); a tool is held where the contact force acts.
    """
    model = description.model
    if model is None or description.tip_frame is None:
        return description.n_links
    return int(model.frames[model.getFrameId(description.tip_frame)].parentJoint)


def payload_angles(description: RobotDescription, link: int) -> tuple[str, ...]:
    """Return the motor angles the pose of ``link`` depends on (``q1``...).

    The model joints supporting the link (pinocchio's ``supports``), through the coupling
    ``q_model = T q_motor`` to the motor joints.
    """
    model = description.model
    if model is None:
        return ()
    supporting = [int(j) - 1 for j in model.supports[link] if int(j) > 0]
    rows = [j for j in supporting if j < description.coupling.shape[0]]
    reached = np.flatnonzero(np.any(description.coupling[rows] != 0.0, axis=0))
    return tuple(f"q{int(k) + 1}" for k in reached)


def payload_candidate(
    samples: SelectedSamples, base: BaseParameters | None, description: RobotDescription
) -> PayloadCandidate | None:
    """Return the payload candidate of a robot with a body (None without one)."""
    directions = payload_directions(base, description)
    if directions is None or base is None:
        return None
    columns = np.concatenate(
        [
            np.einsum("kjp,pc->kjc", item.signals.rigid_regressor[idx], directions)
            for item, idx in zip(samples.prepared, samples.rows, strict=True)
        ]
    )
    energy = np.sum(columns**2, axis=(0, 2))
    reached = tuple(int(j) for j in np.flatnonzero(energy > REACH_SHARE * energy.max()))
    if not reached:
        return None
    link = payload_link(description)
    return PayloadCandidate(directions, columns, reached, payload_angles(description, link), link)


def confirm_payload(
    check: WholeModelCheck,
    veto: WholeModelCheck | None,
    payload: PayloadCandidate,
    options: ResidualOptions,
) -> PayloadConfirmation:
    """Check the payload against the whole model, on held-out blocks and on the veto's data.

    Confirmed when it lowers the held-out RMS of the joint it helps most by
    ``min_rms_gain``, that joint's RMS on the data it was not fitted on (``veto``) by
    ``min_holdout_gain``, and makes no explained joint worse on either.
    """
    before = check.relative_rms()
    after = check.relative_rms(payload.columns)
    gains = 1.0 - after / np.clip(before, 1e-300, None)
    joint = max(payload.reached, key=lambda j: gains[j])
    worse = worse_joints(before, after, options.min_rms_gain)
    holdout_gain = None
    if veto is not None:
        veto_before, veto_after = veto.relative_rms(), veto.relative_rms(payload.columns)
        worse |= worse_joints(veto_before, veto_after, options.min_rms_gain)
        holdout_gain = float(1.0 - veto_after[joint] / max(veto_before[joint], 1e-300))
    holds = holdout_gain is None or holdout_gain >= options.min_holdout_gain
    return PayloadConfirmation(
        confirmed=bool(gains[joint] >= options.min_rms_gain and holds and not worse.any()),
        joint=int(joint),
        gain=float(gains[joint]),
        holdout_gain=holdout_gain,
        worse_joints=tuple(int(k) + 1 for k in np.flatnonzero(worse)),
        after=tuple(after.tolist()),
    )
