"""Robot descriptions by name: built-in robots and description files; each one's defaults."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np

from teleop_force.errors import ModelError
from teleop_force.robots.description import RobotDescription
from teleop_force.robots.driver_interface import DriverInterface
from teleop_force.robots.kinds import BUILTIN_ROBOTS, RobotKind
from teleop_force.robots.omni import omni_description


@dataclass(frozen=True)
class RobotDefaults:
    """The best baseline of a robot: what ``identify`` and ``residual`` fit by default.

    ``friction`` is a friction kind's name (``teleop_force.friction.kinds.FrictionKind``);
    ``offsets``: fit a constant torque per joint (None: only without a rigid body);
    ``sticking``: ``identify --sticking`` (a sticking state for the Coulomb terms where the
    recordings say so; not with ``model-cv``); ``count_observer``: ``identify
    --count-observer`` (estimate on the encoder count observer's angles, for a robot whose
    angles are encoder counts).
    """

    friction: str
    offsets: bool | None = None
    sticking: bool = False
    count_observer: bool = False

    def sticking_with(self, friction: str) -> bool:
        """Whether ``identify`` looks for a sticking state by default with ``friction``."""
        return self.sticking and friction != "model-cv"


#: Per built-in robot (docs/cli.md). The MTM: friction in model coordinates with offsets
#: (its cables and parallelogram; on trajectory two, joints 2 / 3: 17.2 / 24.1 % against
#: 24.5 / 29.3 % with the wavelet network, docs/robots.md); the test stand: CV (its flights
#: are too short to train a network on: ``TeststandOptions`` in estimation/teststand.py);
#: the Omni, ``none`` and description files: the wavelet network (the library's default). The
#: Omni's identification looks for a sticking state (kept only where its free motion fits
#: better with it: none on plant family one, the tuning set; docs/results.md) and estimates on
#: its encoder count observer's angles (docs/accuracy/low_speed.md, tenth session).
BUILTIN_DEFAULTS: dict[RobotKind, RobotDefaults] = {
    RobotKind.OMNI: RobotDefaults("wn", sticking=True, count_observer=True),
    RobotKind.NONE: RobotDefaults("wn"),
    RobotKind.DVRK_MTM: RobotDefaults("model-cv", offsets=True),
    RobotKind.TESTSTAND: RobotDefaults("cv"),
}


def robot_defaults(name: str | RobotKind) -> RobotDefaults:
    """Return the defaults of the robot called ``name`` (a description file: the library's)."""
    if name in BUILTIN_ROBOTS:
        return BUILTIN_DEFAULTS[RobotKind(name)]
    return RobotDefaults("wn")


def friction_only_description(n_joints: int) -> RobotDescription:
    """Return a robot without rigid-body terms: friction and found effects only (``none``)."""
    return RobotDescription(
        name=RobotKind.NONE.value,
        model=None,
        n_joints=n_joints,
        coupling=np.eye(n_joints),
        tip_frame=None,
        rotor_inertia_kgm2=np.zeros(n_joints),
    )


def resolve_robot(name: str | RobotKind, n_joints: int | None = None) -> RobotDescription:
    """Return the description called ``name``: a built-in robot or a ``.json``/``.toml`` file.

    ``none`` needs ``n_joints``; a description file's path is resolved from the current
    folder (the description then carries its absolute path as its name).
    """
    if name in BUILTIN_ROBOTS:
        return _builtin_description(RobotKind(name), n_joints)
    from teleop_force.robots.file import load_robot_description, looks_like_robot_file

    if looks_like_robot_file(name):
        return load_robot_description(name)
    raise ModelError(
        f"unknown robot {name!r}; built-in robots: {', '.join(BUILTIN_ROBOTS)}, "
        "or a robot description file (.json or .toml)"
    )


def _builtin_description(kind: RobotKind, n_joints: int | None) -> RobotDescription:
    """Return the description of a built-in robot (``none`` needs ``n_joints``)."""
    match kind:
        case RobotKind.OMNI:
            return omni_description()
        case RobotKind.NONE:
            if n_joints is None:
                raise ModelError("robot 'none' needs the number of joints")
            return friction_only_description(n_joints)
        case RobotKind.DVRK_MTM:
            from teleop_force.robots.dvrk_mtm import dvrk_mtm_description

            return dvrk_mtm_description()
        case RobotKind.TESTSTAND:
            from teleop_force.robots.teststand import teststand_description

            return teststand_description()


#: Built-in driver interfaces (teleop_force/robots/drivers/), by name.
BUILTIN_DRIVERS: dict[str, str] = {"sensable-phantom": "sensable_phantom.toml"}


def builtin_driver(name: str) -> DriverInterface:
    """Return a built-in driver interface (``sensable-phantom``: sawSensablePhantom's Omni)."""
    from teleop_force.robots.file import load_driver_interface

    if name not in BUILTIN_DRIVERS:
        raise ModelError(f"unknown driver {name!r}; built-in drivers: {', '.join(BUILTIN_DRIVERS)}")
    with resources.as_file(
        resources.files("teleop_force.robots") / "drivers" / BUILTIN_DRIVERS[name]
    ) as path:
        return load_driver_interface(path)


def resolve_driver(name_or_path: str) -> DriverInterface:
    """Return a built-in driver interface by name, else the one a description file holds."""
    from teleop_force.robots.file import load_driver_interface

    if name_or_path in BUILTIN_DRIVERS:
        return builtin_driver(name_or_path)
    return load_driver_interface(name_or_path)
