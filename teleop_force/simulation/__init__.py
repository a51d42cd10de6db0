"""The simulated PHANTOM Omni: plant, true friction, contact, unmodelled effects, PID, protocols.

Everything needed to produce realistic recordings without the hardware: a
:class:`SimulatedOmni` behind the :class:`~teleop_force.robots.device.Device` interface, reference
trajectories for the paper's experiments, and :func:`simulate_session` with ready-made
protocol builders.

Two plant families (:class:`PlantFamily`, :func:`make_plant`): ``ONE`` is the
:class:`SimulatedOmni`; ``TWO`` the held-out :class:`SimulatedOmniTwo` (perturbed inertias per
seed, LuGre friction, other actuator noise and encoders, a Hunt-Crossley floor). Every
protocol builder takes ``family=``. A tip payload: ``tip_mass_kg=`` on either family
(:func:`with_tip_payload` on a description).
"""

from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.effects import EFFECT_NAMES, PlantEffect, make_effect
from teleop_force.simulation.families import PlantFamily, default_contact, make_plant
from teleop_force.simulation.floor_contact import HuntCrossleyFloor

# after session: floor_touch builds on simulate_session
from teleop_force.simulation.floor_touch import (
    FloorTouchTrajectory,
    floor_touch_protocol,
    floor_touch_trajectory,
)
from teleop_force.simulation.lugre_friction import LuGreFriction
from teleop_force.simulation.payload import with_tip_payload
from teleop_force.simulation.pid import PID, PIDGains
from teleop_force.simulation.plant import PlantConfig, SimulatedOmni
from teleop_force.simulation.plant_two import PlantTwoConfig, SimulatedOmniTwo
from teleop_force.simulation.session import (
    SessionOptions,
    SimulatedSession,
    friction_protocol,
    palpation_protocol,
    rigid_body_protocol,
    simulate_session,
    teleoperation_protocol,
)
from teleop_force.simulation.trajectories import (
    Trajectory,
    friction_trajectory,
    palpation_trajectory,
    rigid_body_trajectory,
    teleoperation_trajectory,
)
from teleop_force.simulation.true_friction import TrueFriction

__all__ = [
    "EFFECT_NAMES",
    "PID",
    "FloorTouchTrajectory",
    "HuntCrossleyFloor",
    "LuGreFriction",
    "PIDGains",
    "PlaneContact",
    "PlantConfig",
    "PlantEffect",
    "PlantFamily",
    "PlantTwoConfig",
    "SessionOptions",
    "SimulatedOmni",
    "SimulatedOmniTwo",
    "SimulatedSession",
    "Trajectory",
    "TrueFriction",
    "default_contact",
    "floor_touch_protocol",
    "floor_touch_trajectory",
    "friction_protocol",
    "friction_trajectory",
    "make_effect",
    "make_plant",
    "palpation_protocol",
    "palpation_trajectory",
    "rigid_body_protocol",
    "rigid_body_trajectory",
    "simulate_session",
    "teleoperation_protocol",
    "teleoperation_trajectory",
    "with_tip_payload",
]
