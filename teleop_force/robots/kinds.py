"""The built-in robots a model file, ``--robot`` and the reports name, as one enum."""

from __future__ import annotations

from enum import StrEnum


class RobotKind(StrEnum):
    """A built-in robot; the value is its name in model files, JSON and ``--robot``."""

    #: No rigid body: friction and found effects only (needs the number of joints).
    NONE = "none"
    #: The PHANTOM Omni (the paper's robot).
    OMNI = "omni"
    #: The dVRK master tool manipulator.
    DVRK_MTM = "dvrk-mtm"
    #: The one-joint test stand with a force sensor.
    TESTSTAND = "teststand"


#: Every built-in robot's name, in the order the error messages list them.
BUILTIN_ROBOTS: tuple[str, ...] = tuple(kind.value for kind in RobotKind)
