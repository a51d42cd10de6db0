"""The simulated PHANTOM Omni: plant, true friction, contact, unmodelled effects, PID, protocols.

Everything needed to produce realistic recordings without the hardware: a
:class:`SimulatedOmni` behind the :class:`~teleop_force.robots.device.Device` interface, reference
trajectories for the paper's experiments, and :func:`simulate_session` with ready-made
protocol builders.
"""

from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.effects import EFFECT_NAMES, PlantEffect, make_effect
from teleop_force.simulation.pid import PID, PIDGains
from teleop_force.simulation.plant import PlantConfig, SimulatedOmni
from teleop_force.simulation.session import (
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
    "PIDGains",
    "PlaneContact",
    "PlantConfig",
    "PlantEffect",
    "SimulatedOmni",
    "SimulatedSession",
    "Trajectory",
    "TrueFriction",
    "friction_protocol",
    "friction_trajectory",
    "make_effect",
    "palpation_protocol",
    "palpation_trajectory",
    "rigid_body_protocol",
    "rigid_body_trajectory",
    "simulate_session",
    "teleoperation_protocol",
    "teleoperation_trajectory",
]
