"""The residual watch on the demo's slave streams, simulated offline (tests, benchmarks).

The streams are made as the live system makes them: the simulated Omni under the PID along
the palpation script (the demo's operator), the service's estimator on each sample, the wire
payloads packed as the slave and the service pack them, appended to the watch's ring and
evaluated every second of stream time, with the watch's own estimator of the model
(:class:`~teleop_force.service.watch_residual.WatchResidual`), exactly as the service's thread
does. An effect may be
switched on in the plant mid-session with the demo's calibration (``--plant-effect``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from master_slave.slave import EffectSwitch, _EffectHistory, calibrated_effect
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.service.residual_watch import ResidualWatch, WatchConfig
from teleop_force.service.watch_residual import WatchResidual
from teleop_force.simulation import PID, PIDGains, PlaneContact, PlantConfig, SimulatedOmni
from teleop_force.simulation.trajectories import palpation_trajectory
from teleop_force.transport import messages as m

#: Stamp of the first sample [ns since the epoch].
T0_NS = 1_700_000_000_000_000_000


@dataclass(frozen=True)
class WatchedSession:
    """What the watch said along one simulated session.

    Attributes:
        times_s: Stream time of each evaluation.
        states: The watch's state after each evaluation.
        reports: The first report of each joint, in time order: ``(joint (1-based), stream
            time [s], variable, effect fraction)``.
        switched_at_s: When the effect was switched on (``None``: clean session).
        effect: The effect switched on (its description; ``""``: none).
        effect_joint: The effect's joint, 1-based (``None``: clean session).
        max_effect_fraction: Largest effect fraction any check reached, per joint.
        evaluation_ms: Wall time of each evaluation [ms].

    """

    times_s: tuple[float, ...]
    states: tuple[str, ...]
    reports: tuple[tuple[int, float, str, float], ...]
    switched_at_s: float | None
    effect: str
    effect_joint: int | None
    max_effect_fraction: tuple[float, ...]
    evaluation_ms: tuple[float, ...]

    @property
    def first_report_s(self) -> float | None:
        """Stream time of the first reported dependence (``None``: none)."""
        return self.reports[0][1] if self.reports else None

    @property
    def finding(self) -> tuple[int, str, float] | None:
        """The first finding reported: joint (1-based), variable, effect fraction."""
        if not self.reports:
            return None
        joint, _, variable, fraction = self.reports[0]
        return joint, variable, fraction


def watched_session(
    duration_s: float,
    seed: int,
    switch: EffectSwitch | None = None,
    config: WatchConfig | None = None,
    model: DynamicModel | None = None,
) -> WatchedSession:
    """Simulate the demo's slave along the palpation script and run the watch on it.

    ``model``: the service's model (default: the shipped one, :data:`DEFAULT_MODEL_PATH`).
    """
    plant_config = PlantConfig()
    dt = plant_config.control_period_s
    n_ticks = round(duration_s / dt)
    q_ref, qd_ref = palpation_trajectory(duration_s + 5.0, seed).sample(np.arange(n_ticks) * dt)
    plant = SimulatedOmni(
        plant_config,
        seed=np.random.SeedSequence(seed).spawn(1)[0],
        contact=PlaneContact.horizontal(-0.06),
        q0_rad=q_ref[0],
        qd0_rad_s=qd_ref[0],
    )
    pid = PID(PIDGains.omni(), n_joints=3, control_period_s=dt)
    pid.reset(integral_nm=plant.holding_torque_nm())
    if model is None:
        model = DynamicModel.load(DEFAULT_MODEL_PATH)
    estimator = ForceEstimator(model)
    watch = ResidualWatch(3, config, residual=WatchResidual(model))
    history = _EffectHistory(10_000) if switch is not None else None
    switch_tick = None if switch is None else round(switch.at_s / dt)
    effect_text, effect_joint, switched_at = "", None, None
    times: list[float] = []
    states: list[str] = []
    reports: dict[int, tuple[int, float, str, float]] = {}
    costs_ms: list[float] = []
    max_fraction = np.zeros(3)
    with plant:
        for k in range(n_ticks):
            state = plant.read()
            command = plant.command_torque(pid.update(q_ref[k], state.q_rad, qd_ref[k]))
            q = state.q_rad.tolist()
            tau = command.tau_nm.tolist()
            stamp = T0_NS + k * 1_000_000
            js = m.pack_joint_state(k, stamp, q, pid.velocity_rad_s.tolist(), tau)
            out = estimator.step(k * dt, q, tau).tolist()
            values = [*out[:3], *out[3:6], *out[12:15], *out[6:12]]
            watch.append(js, m.pack_force_estimate(k, stamp, k, 3, values, 7))
            if history is not None and switch is not None:
                history.add(state.q_rad, pid.velocity_rad_s, command.tau_nm)
                if k == switch_tick:
                    hq, hqd, htau = history.window()
                    effect = calibrated_effect(
                        switch, plant.t_s, history.rms_torque_nm(), hq, hqd, htau
                    )
                    plant.effects = (effect,)
                    effect_text, effect_joint = effect.describe(), effect.joint + 1
                    switched_at = k * dt
            plant.step()
            if k % 1000 == 999:
                started = time.perf_counter()
                checks = watch.evaluate()
                costs_ms.append((time.perf_counter() - started) * 1e3)
                times.append(watch.stream_s)
                states.append(watch.state)
                for c in checks:
                    max_fraction[c.joint] = max(max_fraction[c.joint], c.effect_fraction)
                for j, f in watch.findings.items():
                    if j + 1 not in reports:
                        reports[j + 1] = (j + 1, watch.stream_s, f.variable, f.effect_fraction)
    return WatchedSession(
        times_s=tuple(times),
        states=tuple(states),
        reports=tuple(sorted(reports.values(), key=lambda r: r[1])),
        switched_at_s=switched_at,
        effect=effect_text,
        effect_joint=effect_joint,
        max_effect_fraction=tuple(float(x) for x in max_fraction),
        evaluation_ms=tuple(costs_ms),
    )
