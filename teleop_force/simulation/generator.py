"""The plant generator: a simulated Omni whose structure is drawn per seed.

Specification: docs/plant_generator.md.

:func:`draw_plant` draws a :class:`DrawnPlant` from :data:`~generator_spec.SPEC`:
per-joint friction law, cable form, arm, sensing, controller, motions and the planted effect.
A drawn plant runs on plant family two's compiled kernel (:mod:`plant_two`) with the drawn
arm and settings; :meth:`DrawnPlant.make_device` builds it behind ``Device`` and
:meth:`DrawnPlant.session` simulates one of its sessions. The fixed families are two draws
of the same type: :func:`family_one_draw`, :func:`family_two_draw`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from teleop_force.errors import ConfigurationError
from teleop_force.robots.device import Device
from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.effects import PlantEffect, default_strength, make_effect
from teleop_force.simulation.families import PlantFamily, make_plant
from teleop_force.simulation.floor_contact import HuntCrossleyFloor
from teleop_force.simulation.generator_spec import (
    CABLE_FORMS,
    CONTACT_KINDS,
    FRICTION_LAWS,
    MOTION_KINDS,
    PLANTED_EFFECTS,
    SPEC,
    PlantGeneratorSpec,
)
from teleop_force.simulation.lugre_friction import LuGreFriction
from teleop_force.simulation.pid import PIDGains
from teleop_force.simulation.plant import PlantConfig
from teleop_force.simulation.plant_two import Contact, DrawnArm, PlantTwoConfig
from teleop_force.simulation.session import SimulatedSession, simulate_session
from teleop_force.simulation.trajectories import (
    Trajectory,
    palpation_trajectory,
    rigid_body_trajectory,
    slow_stretch_trajectory,
    teleoperation_trajectory,
)

#: Surface height of the palpation contact [m] (the protocols' default).
SURFACE_Y_M = -0.06


@dataclass(frozen=True, eq=False)
class DrawnPlant:
    """One draw: the plant's structure, settings and sessions.

    Attributes:
        seed: The draw's seed (``None`` for the fixed families).
        kernel: ``"one"`` (family one's plant) or ``"two"`` (family two's kernel).
        config: The plant's configuration.
        friction_laws: Per joint, one of :data:`FRICTION_LAWS` (family one: ``stribeck``).
        cable_form: One of :data:`CABLE_FORMS` (family one: ``load-coupled``).
        pid_gains: The controller.
        identification_motion: Motion kind of the identification session.
        test_motion: Motion kind of the free-motion test session (another kind).
        contact_kind: ``tissue`` or ``floor`` for the palpation.
        contact_stiffness_scale: Its stiffness relative to the family's default.
        planted_effect: The residual-loop session's effect (``make_effect`` name).
        effect_strength_scale: Its strength relative to the default.

    """

    seed: int | None
    kernel: str
    config: PlantConfig | PlantTwoConfig
    friction_laws: tuple[str, str, str]
    cable_form: str
    pid_gains: PIDGains
    identification_motion: str
    test_motion: str
    contact_kind: str
    contact_stiffness_scale: float
    planted_effect: str
    effect_strength_scale: float

    def __post_init__(self) -> None:
        if self.kernel not in ("one", "two"):
            raise ConfigurationError(f"kernel must be 'one' or 'two', got {self.kernel!r}")
        if self.identification_motion == self.test_motion:
            raise ConfigurationError("the identification and test motions must differ")
        for kind in (self.identification_motion, self.test_motion):
            if kind not in MOTION_KINDS:
                raise ConfigurationError(f"unknown motion kind {kind!r}")
        if self.contact_kind not in CONTACT_KINDS:
            raise ConfigurationError(f"unknown contact kind {self.contact_kind!r}")
        if self.planted_effect not in PLANTED_EFFECTS:
            raise ConfigurationError(f"unknown planted effect {self.planted_effect!r}")

    @property
    def family(self) -> PlantFamily:
        """The family whose kernel runs the plant."""
        return PlantFamily(self.kernel)

    def structure(self) -> dict[str, Any]:
        """Return the drawn structure, JSON-ready (what a report's table shows)."""
        config = self.config
        sensing: dict[str, Any] = {}
        if isinstance(config, PlantTwoConfig):
            sensing = {
                "encoder_resolution_rad": list(config.encoder_resolution_rad),
                "torque_noise_std_nm": config.torque_noise_std_nm,
                "dac_step_nm": config.dac_step_nm,
                "ripple_fraction": config.ripple_fraction,
            }
        return {
            "seed": self.seed,
            "kernel": self.kernel,
            "friction_laws": list(self.friction_laws),
            "cable_form": self.cable_form,
            "identification_motion": self.identification_motion,
            "test_motion": self.test_motion,
            "contact": self.contact_kind,
            "planted_effect": self.planted_effect,
            **sensing,
        }

    def contact(self, surface_y_m: float = SURFACE_Y_M) -> Contact:
        """Return the palpation's contact at ``y = surface_y_m``, with the drawn stiffness."""
        scale = self.contact_stiffness_scale
        if self.contact_kind == "floor" and self.kernel == "two":
            stiffness = HuntCrossleyFloor().stiffness_n_per_m_e * scale
            return HuntCrossleyFloor.horizontal(surface_y_m, stiffness_n_per_m_e=stiffness)
        stiffness = PlaneContact().stiffness_n_per_m * scale
        return PlaneContact.horizontal(surface_y_m, stiffness_n_per_m=stiffness)

    def effect(self) -> PlantEffect:
        """Return the planted effect at its default joint, with the drawn strength."""
        strength = default_strength(self.planted_effect) * self.effect_strength_scale
        return make_effect(self.planted_effect, strength=strength)

    def make_device(
        self,
        *,
        seed: int | np.random.SeedSequence | None = 0,
        effects: tuple[PlantEffect, ...] = (),
        contact: Contact | None = None,
        q0_rad: ArrayLike | None = None,
    ) -> Device:
        """Build the plant behind ``Device`` (``seed``: the actuator noise)."""
        return make_plant(
            self.family, seed=seed, effects=effects, contact=contact, config=self.config,
            q0_rad=q0_rad,
        )  # fmt: skip

    def session(
        self,
        motion: str,
        duration_s: float,
        seed: int,
        *,
        effects: tuple[PlantEffect, ...] = (),
    ) -> SimulatedSession:
        """Simulate ``duration_s`` of ``motion`` (a kind, or ``palpation`` on the contact)."""
        contact = self.contact() if motion == "palpation" else None
        return simulate_session(
            motion_trajectory(motion, duration_s, seed),
            duration_s,
            seed,
            effects=effects,
            contact=contact,
            plant_config=self.config,
            pid_gains=self.pid_gains,
            name=motion,
            family=self.family,
        )


def motion_trajectory(kind: str, duration_s: float, seed: int) -> Trajectory:
    """Return the reference of a motion kind (:data:`MOTION_KINDS` or ``palpation``)."""
    if kind == "multi-sine":
        return rigid_body_trajectory(seed)
    if kind == "teleoperation":
        return teleoperation_trajectory(seed)
    if kind == "slow-stretch":
        return slow_stretch_trajectory(duration_s, seed)
    if kind == "palpation":
        return palpation_trajectory(duration_s, seed, surface_y_m=SURFACE_Y_M)
    raise ConfigurationError(f"unknown motion kind {kind!r}")


def _one(rng: np.random.Generator, draw: Any) -> float:
    return float(draw.sample(rng)[0])


def _choice(rng: np.random.Generator, options: tuple[Any, ...]) -> Any:
    return options[int(rng.integers(len(options)))]


def _friction(
    rng: np.random.Generator, spec: PlantGeneratorSpec
) -> tuple[LuGreFriction, tuple[str, str, str], str]:
    """Draw the per-joint laws and the cable (in the spec's order) as one LuGre table."""
    f, c = spec.friction, spec.cable
    base = LuGreFriction()
    laws = tuple(_choice(rng, FRICTION_LAWS) for _ in range(3))
    columns: dict[str, list[float]] = {
        key: []
        for key in ("sigma0", "sigma1", "sigma2", "fc", "fs", "vs", "vd")
    }  # fmt: skip
    for j, law in enumerate(laws):
        fc = base.coulomb_nm[j] * _one(rng, f.coulomb_scale)
        viscous = base.viscous_nms_per_rad[j] * _one(rng, f.viscous_scale)
        stribeck = law in ("stribeck", "lugre")
        fs = fc * _one(rng, f.static_ratio) if stribeck else fc
        vs = _one(rng, f.stribeck_velocity_rad_s) if stribeck else f.flat_stribeck_velocity_rad_s
        if law in ("lugre", "dahl"):
            sigma0 = _one(rng, f.soft_bristle_nm_per_rad)
            sigma1 = _one(rng, f.soft_damping_nms_per_rad) if law == "lugre" else 0.0
        else:
            sigma0, sigma1 = f.stiff_bristle_nm_per_rad, f.stiff_damping_nms_per_rad
        for key, value in zip(
            columns, (sigma0, sigma1, viscous, fc, fs, vs, f.damping_velocity_rad_s), strict=True
        ):
            columns[key].append(value)
    form = _choice(rng, CABLE_FORMS)
    ratio = _one(rng, c.pulley_ratio)
    fcc = _one(rng, c.coulomb_nm)
    fsc = fcc * _one(rng, c.static_ratio)
    bc = _one(rng, c.viscous_nms_per_rad)
    vsc = _one(rng, c.stribeck_velocity_rad_s)
    sigma0c, sigma1c = _one(rng, c.soft_bristle_nm_per_rad), _one(rng, c.soft_damping_nms_per_rad)
    if form == "none":
        fcc = fsc = c.absent_level_nm
        bc = 0.0
    if form != "hysteretic":
        sigma0c, sigma1c = f.stiff_bristle_nm_per_rad, f.stiff_damping_nms_per_rad
    for key, value in zip(
        columns, (sigma0c, sigma1c, bc, fcc, fsc, vsc, f.damping_velocity_rad_s), strict=True
    ):
        columns[key].append(value)
    friction = LuGreFriction(
        bristle_stiffness_nm_per_rad=tuple(columns["sigma0"]),  # type: ignore[arg-type]
        bristle_damping_nms_per_rad=tuple(columns["sigma1"]),  # type: ignore[arg-type]
        viscous_nms_per_rad=tuple(columns["sigma2"]),  # type: ignore[arg-type]
        coulomb_nm=tuple(columns["fc"]),  # type: ignore[arg-type]
        static_nm=tuple(columns["fs"]),  # type: ignore[arg-type]
        stribeck_velocity_rad_s=tuple(columns["vs"]),  # type: ignore[arg-type]
        damping_velocity_rad_s=tuple(columns["vd"]),  # type: ignore[arg-type]
        pulley_ratio=ratio,
    )
    return friction, (laws[0], laws[1], laws[2]), form


def draw_plant(seed: int, spec: PlantGeneratorSpec = SPEC) -> DrawnPlant:
    """Draw the plant of ``seed`` from ``spec`` (deterministic: the same seed, the same plant).

    Raises:
        ConfigurationError: for a seed that is not an integer >= 0.

    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigurationError(f"seed must be an integer >= 0, got {seed!r}")
    rng = np.random.default_rng(np.random.SeedSequence([spec.stream_tag, int(seed)]))
    inertia_seed = int(rng.integers(2**32))
    spring_scale = float(rng.uniform(1.0 - spec.arm.spread, 1.0 + spec.arm.spread))
    friction, laws, form = _friction(rng, spec)
    s = spec.sensing
    resolution = s.encoder_resolution_rad.sample(rng, 3)
    noise_std = _one(rng, s.torque_noise_std_nm)
    noise_correlation = _one(rng, s.torque_noise_correlation_s)
    ripple = _one(rng, s.ripple_fraction)
    wavenumber = _one(rng, s.ripple_wavenumber_per_rad)
    bits = int(_choice(rng, s.dac_bits))
    omni = PIDGains.omni()
    gains = PIDGains(
        kp_nm_per_rad=omni.kp_nm_per_rad * s.gain_scale.sample(rng, 3),
        ki_nm_per_rad_s=omni.ki_nm_per_rad_s * s.gain_scale.sample(rng, 3),
        kd_nms_per_rad=omni.kd_nms_per_rad * s.gain_scale.sample(rng, 3),
        derivative_cutoff_hz=_one(rng, s.derivative_cutoff_hz),
    )
    m = spec.motion
    identification = _choice(rng, MOTION_KINDS)
    test = _choice(rng, tuple(kind for kind in MOTION_KINDS if kind != identification))
    config = PlantTwoConfig(
        instance_seed=0,
        spread=spec.arm.spread,
        torque_noise_std_nm=noise_std,
        torque_noise_correlation_s=noise_correlation,
        dac_step_nm=s.dac_full_range_nm / 2**bits,
        ripple_fraction=ripple,
        ripple_wavenumber_per_rad=wavenumber,
        encoder_resolution_rad=(float(resolution[0]), float(resolution[1]), float(resolution[2])),
        drawn_arm=DrawnArm(inertia_seed, spec.arm.spread, friction, spring_scale),
    )
    return DrawnPlant(
        seed=int(seed),
        kernel="two",
        config=config,
        friction_laws=laws,
        cable_form=form,
        pid_gains=gains,
        identification_motion=identification,
        test_motion=test,
        contact_kind=_choice(rng, CONTACT_KINDS),
        contact_stiffness_scale=_one(rng, m.contact_stiffness_scale),
        planted_effect=_choice(rng, PLANTED_EFFECTS),
        effect_strength_scale=_one(rng, m.effect_strength_scale),
    )


def family_one_draw() -> DrawnPlant:
    """Plant family one as a draw (its own plant, gains and tissue; a multi-sine identification)."""
    return DrawnPlant(
        seed=None,
        kernel="one",
        config=PlantConfig(),
        friction_laws=("stribeck", "stribeck", "stribeck"),
        cable_form="load-coupled",
        pid_gains=PIDGains.omni(),
        identification_motion="multi-sine",
        test_motion="teleoperation",
        contact_kind="tissue",
        contact_stiffness_scale=1.0,
        planted_effect="cogging",
        effect_strength_scale=1.0,
    )


def family_two_draw(instance_seed: int) -> DrawnPlant:
    """Plant family two, instance ``instance_seed``, as a draw (LuGre everywhere, the floor)."""
    return DrawnPlant(
        seed=None,
        kernel="two",
        config=PlantTwoConfig(instance_seed=instance_seed),
        friction_laws=("lugre", "lugre", "lugre"),
        cable_form="hysteretic",
        pid_gains=PIDGains.omni(),
        identification_motion="multi-sine",
        test_motion="teleoperation",
        contact_kind="floor",
        contact_stiffness_scale=1.0,
        planted_effect="cogging",
        effect_strength_scale=1.0,
    )
