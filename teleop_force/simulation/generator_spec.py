"""The plant generator's specification: every distribution a drawn plant comes from.

Frozen before anything was run on the generator (docs/plant_generator.md says what was run
when). A plant is drawn from :data:`SPEC` by :func:`~teleop_force.simulation.generator.draw_plant`
with ``numpy.random.default_rng(SeedSequence([SPEC.stream_tag, seed]))``, in the order of
:class:`PlantGeneratorSpec`'s fields. Seeds :data:`CHOICE_SEEDS` (1-20) serve every choice;
the reported seeds come from :func:`reported_seeds` of the commit that freezes the last
choice, so that nobody can have looked at them before.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field

import numpy as np

from teleop_force.errors import ConfigurationError

#: Seeds on which every choice (threshold, default, structure) is made.
CHOICE_SEEDS: tuple[int, ...] = tuple(range(1, 21))
#: Number of reported seeds.
N_REPORTED_SEEDS = 20
#: The reported seeds lie in ``[REPORTED_SEED_LOW, REPORTED_SEED_HIGH)``, disjoint from 1-20.
REPORTED_SEED_LOW = 1000
REPORTED_SEED_HIGH = 1_000_000

#: Friction laws a joint can draw.
FRICTION_LAWS: tuple[str, ...] = ("coulomb-viscous", "stribeck", "lugre", "dahl")
#: Forms of the joint-2/3 cable coupling.
CABLE_FORMS: tuple[str, ...] = ("none", "static", "hysteretic")
#: Motion kinds; identification and free-motion test draw different ones.
MOTION_KINDS: tuple[str, ...] = ("multi-sine", "teleoperation", "slow-stretch")
#: Contact-force test motion (always).
CONTACT_MOTION = "palpation"
#: Contacts the palpation can meet.
CONTACT_KINDS: tuple[str, ...] = ("tissue", "floor")
#: Planted effects of the residual-loop session (default joints, as the blind tests name them).
PLANTED_EFFECTS: tuple[str, ...] = (
    "cogging",
    "position-friction",
    "drifting-friction",
    "load-friction",
    "elbow-bump",
    "cross-direction-offset",
)


@dataclass(frozen=True)
class Draw:
    """A scalar distribution: ``uniform`` on ``[low, high]`` or ``log`` (log-uniform)."""

    low: float
    high: float
    scale: str = "uniform"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low <= self.high):
            raise ConfigurationError(f"need finite low <= high, got {self.low}, {self.high}")
        if self.scale not in ("uniform", "log"):
            raise ConfigurationError(f"scale must be 'uniform' or 'log', got {self.scale!r}")
        if self.scale == "log" and self.low <= 0.0:
            raise ConfigurationError(f"a log-uniform draw needs low > 0, got {self.low}")

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        """Draw ``size`` values (one if ``None``) as an array."""
        n = 1 if size is None else size
        if self.scale == "log":
            return np.exp(rng.uniform(math.log(self.low), math.log(self.high), size=n))
        return rng.uniform(self.low, self.high, size=n)

    def contains(self, value: float) -> bool:
        """Whether ``value`` is in the support (a relative slack of 1e-12 for round-off)."""
        slack = 1e-12 * max(abs(self.low), abs(self.high), 1.0)
        return bool(self.low - slack <= value <= self.high + slack)


@dataclass(frozen=True)
class FrictionLawSpec:
    """Per-joint friction: the law (uniform over :data:`FRICTION_LAWS`) and its parameters.

    Every law is a LuGre element (:mod:`~teleop_force.simulation.lugre_friction`) with:

    - ``coulomb-viscous``: stiff bristle (``sigma0 = stiff_bristle``), ``Fs = Fc``: in sliding
      ``Fc sgn(v) + b v``; the bristle deflection ``Fc / sigma0`` is below a tenth of the
      finest encoder count.
    - ``stribeck``: stiff bristle, ``Fs = Fc * static_ratio``, Stribeck velocity ``vs``: a
      static Stribeck map, no measurable pre-sliding.
    - ``lugre``: soft bristle ``sigma0`` and micro-damping ``sigma1``, Stribeck ``Fs``, ``vs``.
    - ``dahl``: soft bristle, ``sigma1 = 0``, ``Fs = Fc`` (no Stribeck): Dahl's pre-sliding
      hysteresis ``dz/dt = v - sigma0 |v| z / Fc``, ``F = sigma0 z + b v``.

    Levels scale family two's LuGre defaults per joint (``Fc``, ``b``).
    """

    coulomb_scale: Draw = Draw(0.5, 2.0, "log")
    viscous_scale: Draw = Draw(0.5, 2.0, "log")
    static_ratio: Draw = Draw(1.3, 2.5)
    stribeck_velocity_rad_s: Draw = Draw(0.02, 0.15, "log")
    soft_bristle_nm_per_rad: Draw = Draw(15.0, 60.0, "log")
    soft_damping_nms_per_rad: Draw = Draw(0.02, 0.1, "log")
    stiff_bristle_nm_per_rad: float = 2000.0
    stiff_damping_nms_per_rad: float = 0.5
    damping_velocity_rad_s: float = 0.05
    #: ``vs`` written for the laws without a Stribeck hump (``Fs = Fc``: it has no effect).
    flat_stribeck_velocity_rad_s: float = 1.0


@dataclass(frozen=True)
class CableSpec:
    """The joint-2/3 cable: form uniform over :data:`CABLE_FORMS`, on ``w = qd2 - r qd3``.

    ``none``: no cable element (its levels are 1e-9 N m); ``static``: a stiff-bristle Stribeck
    element; ``hysteretic``: a LuGre element with a soft bristle. Its torque acts ``+F`` on
    joint 2 and ``-r F`` on joint 3 (passive).
    """

    pulley_ratio: Draw = Draw(0.75, 1.0)
    coulomb_nm: Draw = Draw(0.003, 0.012, "log")
    static_ratio: Draw = Draw(1.2, 2.0)
    viscous_nms_per_rad: Draw = Draw(1.2e-3, 5e-3, "log")
    stribeck_velocity_rad_s: Draw = Draw(0.02, 0.1, "log")
    soft_bristle_nm_per_rad: Draw = Draw(10.0, 40.0, "log")
    soft_damping_nms_per_rad: Draw = Draw(0.02, 0.08, "log")
    absent_level_nm: float = 1e-9


@dataclass(frozen=True)
class ArmSpec:
    """Masses and spring, each scaled by ``U(1 - spread, 1 + spread)``.

    Every link mass, centre-of-mass coordinate and inertia entry, each rotor inertia
    (:func:`~teleop_force.simulation.perturbed_omni.perturbed_omni_description`) and the
    gravity-compensation spring stiffness.
    """

    spread: float = 0.3


@dataclass(frozen=True)
class SensingSpec:
    """Encoders, actuator and controller (plant family two's actuator model, drawn).

    Encoder counts per joint; torque noise coloured (AR(1)); ripple
    ``ripple_fraction |tau| sin(k q)``; DAC step ``dac_full_range_nm / 2^bits`` with ``bits``
    uniform over ``dac_bits``; PID gains: Kp, Ki, Kd per joint each
    ``PIDGains.omni() * U(0.7, 1.3)`` and the derivative cut-off drawn.
    """

    encoder_resolution_rad: Draw = Draw(2.5e-4, 8e-4)
    torque_noise_std_nm: Draw = Draw(5e-4, 3e-3, "log")
    torque_noise_correlation_s: Draw = Draw(1e-3, 1e-2, "log")
    ripple_fraction: Draw = Draw(0.0, 0.01)
    ripple_wavenumber_per_rad: Draw = Draw(48.0, 144.0)
    dac_bits: tuple[int, ...] = (10, 11, 12, 14)
    dac_full_range_nm: float = 1.2
    gain_scale: Draw = Draw(0.7, 1.3)
    derivative_cutoff_hz: Draw = Draw(20.0, 40.0)


@dataclass(frozen=True)
class MotionSpec:
    """Motions of a drawn plant's sessions.

    The identification kind uniform over :data:`MOTION_KINDS`; the free-motion test
    kind uniform over the other two; the contact test a palpation of a contact drawn from
    :data:`CONTACT_KINDS` (the families' defaults with stiffness ``* contact_stiffness_scale``).
    The residual loop gets a clean session and a session with one effect uniform over
    :data:`PLANTED_EFFECTS` (its default joint, strength ``* effect_strength_scale``), both of
    the identification kind. Durations in seconds.
    """

    identification_s: float = 60.0
    test_s: float = 30.0
    palpation_s: float = 30.0
    residual_s: float = 60.0
    contact_stiffness_scale: Draw = Draw(0.5, 2.0, "log")
    effect_strength_scale: Draw = Draw(0.7, 1.5)


@dataclass(frozen=True)
class PlantGeneratorSpec:
    """The whole specification (module docstring); the draw follows the fields' order."""

    stream_tag: int = 34
    arm: ArmSpec = field(default_factory=ArmSpec)
    friction: FrictionLawSpec = field(default_factory=FrictionLawSpec)
    cable: CableSpec = field(default_factory=CableSpec)
    sensing: SensingSpec = field(default_factory=SensingSpec)
    motion: MotionSpec = field(default_factory=MotionSpec)


#: The frozen specification.
SPEC = PlantGeneratorSpec()

_COMMIT = re.compile(r"^[0-9a-f]{40}$")


def reported_seeds(commit_id: str, count: int = N_REPORTED_SEEDS) -> tuple[int, ...]:
    """Return the reported seeds of the commit ``commit_id`` (40 lower-case hex digits).

    ``entropy = int(sha256(commit_id.encode("ascii")).hexdigest(), 16)``; the state
    ``SeedSequence(entropy).generate_state(4 * count, dtype=uint32)`` (stable across NumPy
    versions) maps each word ``s`` to ``REPORTED_SEED_LOW + s % (REPORTED_SEED_HIGH -
    REPORTED_SEED_LOW)``; the first ``count`` distinct values, in order.

    Raises:
        ConfigurationError: if ``commit_id`` is not a full commit id.

    """
    if not _COMMIT.match(commit_id):
        raise ConfigurationError(f"need a full 40-digit lower-case commit id, got {commit_id!r}")
    entropy = int(hashlib.sha256(commit_id.encode("ascii")).hexdigest(), 16)
    words = np.random.SeedSequence(entropy).generate_state(4 * count, dtype=np.uint32)
    span = REPORTED_SEED_HIGH - REPORTED_SEED_LOW
    seeds: list[int] = []
    for word in words:
        seed = REPORTED_SEED_LOW + int(word) % span
        if seed not in seeds:
            seeds.append(seed)
        if len(seeds) == count:
            return tuple(seeds)
    raise ConfigurationError("not enough distinct seeds")  # pragma: no cover - p ~ 0
