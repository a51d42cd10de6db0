"""The friction kinds a model file, ``identify`` and ``residual`` name, as one enum."""

from __future__ import annotations

from enum import StrEnum

from teleop_force.errors import ConfigurationError


class FrictionKind(StrEnum):
    """A friction model family; the value is its name in model files, JSON and the CLI."""

    #: Coulomb-viscous per joint, on the joint's own velocity.
    CV = "cv"
    #: Coulomb-viscous with the cross-joint terms of the robot's coupling (the Omni's cable).
    COUPLED_CV = "coupled-cv"
    #: Coulomb-viscous acting in model coordinates, through the robot's joint coupling.
    MODEL_CV = "model-cv"
    #: Wavelet network (the paper's method) with a coupled CV, combined by its coverage trust
    #: (:data:`WN_STRUCTURES`).
    WN = "wn"

    @classmethod
    def parse(cls, value: str | FrictionKind, what: str = "friction") -> FrictionKind:
        """Return the kind named ``value``; raise :class:`ConfigurationError` naming the choices."""
        try:
            return cls(value)
        except ValueError:
            choices = ", ".join(kind.value for kind in cls)
            raise ConfigurationError(
                f"unknown {what} {value!r}; expected one of {choices}"
            ) from None


#: Every friction kind's name, in the order the CLI lists them.
FRICTION_KINDS: tuple[str, ...] = tuple(kind.value for kind in FrictionKind)

#: The wavelet network's structures by their command-line names (``--wn-structure``): ``on-cv``
#: (the default) is trained on what the coupled CV leaves and adds to it, ``alone`` is the
#: paper's network, the whole friction, blended with the coupled CV off its trained ground.
WN_STRUCTURES: tuple[str, ...] = ("on-cv", "alone")


def wn_on_fallback(structure: str) -> bool:
    """Return whether the structure called ``structure`` adds the network to the coupled CV.

    Raise :class:`ConfigurationError` naming the choices if there is no such structure.
    """
    if structure not in WN_STRUCTURES:
        raise ConfigurationError(
            f"wn structure must be one of {', '.join(WN_STRUCTURES)}, got {structure!r}"
        )
    return structure == WN_STRUCTURES[0]


def wn_structure_name(on_fallback: bool) -> str:
    """Return the name of the structure that does (``on_fallback``) or does not add to the CV."""
    return WN_STRUCTURES[0] if on_fallback else WN_STRUCTURES[1]
