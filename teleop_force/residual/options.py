"""Knobs of the residual loop and its typed choices.

Light on purpose: the command line lists the choices from these enums at start-up, without
importing the loop (NumPy, SciPy, the identification pipeline).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum

from teleop_force.errors import ConfigurationError
from teleop_force.friction.kinds import FrictionKind


class EffectPlacement(StrEnum):
    """Where an effect found on motor ``j`` acts; the value is its name on the command line."""

    #: ``either`` with friction in model coordinates, else ``motor``.
    AUTO = "auto"
    #: On motor ``j`` alone.
    MOTOR = "motor"
    #: At model joint ``j``, reaching the motors through the coupling (``FoundEffect.reach``).
    MODEL = "model"
    #: The model joint if the whole model confirms it there, else motor ``j`` alone.
    EITHER = "either"

    def resolved(self, friction: FrictionKind) -> EffectPlacement:
        """Return the placement ``auto`` stands for with ``friction`` (others: themselves)."""
        if self is not EffectPlacement.AUTO:
            return self
        if friction is FrictionKind.MODEL_CV:
            return EffectPlacement.EITHER
        return EffectPlacement.MOTOR


#: The friction kinds ``teleop-force residual --friction`` offers: every kind.
COMMAND_LINE_FRICTION_KINDS: tuple[FrictionKind, ...] = (
    FrictionKind.CV,
    FrictionKind.COUPLED_CV,
    FrictionKind.MODEL_CV,
    FrictionKind.WN,
)


@dataclass(frozen=True)
class ResidualOptions:
    """Knobs of the residual loop.

    ``friction`` and ``effect_placement`` also take their names as strings (the enums'
    values); they are stored as the enums.
    """

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
    #: Friction of the model the residual is taken from; None: the robot's default
    #: (:func:`~teleop_force.robots.registry.robot_defaults`, :meth:`for_robot`).
    friction: FrictionKind | None = None
    #: Ridge of the held-out fits (column-scaled) and of the final fit's effect columns.
    ridge: float = 1e-4
    #: Fit a constant torque per joint; None: the robot's default (only without rigid-body
    #: terms, with them on the dVRK MTM).
    offsets: bool | None = None
    #: Candidates, best first, checked against the whole model per step
    #: (:class:`~teleop_force.residual.scoring.WholeModelCheck`).
    confirm_candidates: int = 20
    #: Also cut periodic recordings into held-out blocks by phase
    #: (:func:`~teleop_force.residual.scoring.trajectory_period`) and refuse an effect that
    #: raises a joint's error on them.
    phase_folds: bool = True
    #: Contiguous blocks of the period each phase fold holds out (1: a fold is one stretch of
    #: a fifth of the period). An effect must then carry over a whole stretch of the
    #: trajectory it was not fitted on; with several short blocks per fold a pose pattern of
    #: the trajectory passes by interpolating between neighbouring phases (the dVRK MTM,
    #: ``--robot none``: 4 blocks per fold let joint 3 take ``q5-q7``, 130 % on trajectory
    #: two; 1 block: 87 %).
    phase_blocks_per_fold: int = 1
    #: Where an effect found on motor j acts (:class:`EffectPlacement`).
    effect_placement: EffectPlacement = EffectPlacement.AUTO
    #: An effect must also lower its joint's RMS by this much on data it was not found on:
    #: the other recordings (leave one recording out) when there are several, else blocks
    #: held out by phase on periodic motion (0: it need only not make a joint worse there).
    min_holdout_gain: float = 0.02
    #: Candidates whose held-out gain is within this fraction of the best one's are tried
    #: fewest parameters first (1, the default: best gain first, always; 0.85 cost the dVRK MTM
    #: its held-out accuracy on trajectory two, 14.1 -> 17.9 % on joint 3).
    parsimony: float = 1.0

    def __post_init__(self) -> None:
        if self.folds < 3:
            raise ConfigurationError("folds must be >= 3")
        if not 0 < self.min_rms_gain < 1:
            raise ConfigurationError("min_rms_gain must be in (0, 1)")
        if not 0 <= self.min_control_gain < 1:
            raise ConfigurationError("min_control_gain must be in [0, 1)")
        for name, kind, what in (
            ("friction", FrictionKind, "residual friction"),
            ("effect_placement", EffectPlacement, "effect placement"),
        ):
            value = getattr(self, name)
            if value is None:
                continue
            try:
                object.__setattr__(self, name, kind(value))
            except ValueError:
                choices = ", ".join(choice.value for choice in kind)
                raise ConfigurationError(
                    f"{what} must be one of {choices}, got {value!r}"
                ) from None
        if not 0 < self.parsimony <= 1:
            raise ConfigurationError("parsimony must be in (0, 1]")
        if not 0 <= self.min_holdout_gain < 1:
            raise ConfigurationError("min_holdout_gain must be in [0, 1)")
        if self.phase_blocks_per_fold < 1:
            raise ConfigurationError("phase_blocks_per_fold must be >= 1")
        if self.decimate < 1:
            raise ConfigurationError("decimate must be >= 1")
        if self.confirm_candidates < 1:
            raise ConfigurationError("confirm_candidates must be >= 1")

    @property
    def placement(self) -> EffectPlacement:
        """The effect placement with ``auto`` resolved for this friction."""
        return self.effect_placement.resolved(self.friction or FrictionKind.WN)

    def for_robot(self, robot: str, has_rigid_body: bool) -> ResidualOptions:
        """Return these options with the friction and offsets left to the robot filled in."""
        from teleop_force.robots.registry import robot_defaults

        defaults = robot_defaults(robot)
        offsets = self.offsets if self.offsets is not None else defaults.offsets
        return replace(
            self,
            friction=self.friction or FrictionKind(defaults.friction),
            offsets=(not has_rigid_body) if offsets is None else offsets,
        )
