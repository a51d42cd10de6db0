"""The slave Omni process: a simulated Omni touching a soft tissue, following the master.

Every 1 ms tick (``RateLoop``, perf_counter deadlines)::

    read the plant (measured q, true tip force)
    safety: follow the latest master setpoint, or hold (SafetyMonitor)
    PID toward the (slew-limited) setpoint, plus extra damping while holding
    command the torque, publish the JointState and the true force, step the plant

Published (``<slave>`` = ``--device``; ROS 2 topics of the node ``teleop_force_slave`` on
rmw_zenoh's keys, :mod:`master_slave.ros2_outputs`)::

    /<slave>/measured_js        sensor_msgs/JointState: measured q, qd (filtered difference),
                                effort = the commanded (clipped) motor torque; stamp = tick time
    /<slave>/true_cf            geometry_msgs/WrenchStamped: the plant's true tip force, same stamp
    /<slave>/status             teleop_force_msgs/Status: on every change and every 100 ms
    omni/<slave>/alive/slave    liveliness token
    omni/<slave>/stats/slave    queryable: JSON statistics (loop, setpoints, safety)

The stamp of tick ``k`` is its nominal time ``start + k * 1 ms``: the plant advances
exactly one period per tick, so stamp differences are the simulated sample period (what the
estimator differentiates with), and a tick that runs late shows as latency downstream.

Subscribed: ``/<master>/setpoint_js`` (sensor_msgs/JointState, positions) and the master's
liveliness token
``omni/<master>/alive/master``. SAFETY: when the token disappears or the last setpoint arrived
more than ``--stale-ms`` (50) ago, the slave holds in the same tick: the setpoint is frozen at
the current measured q and extra joint damping is added; Status HOLDING gives the reason. It
follows again (slew-limited, no jump) once ``resume_count`` fresh setpoints have arrived with
the token present. Malformed setpoints (or of other joint names) are counted and dropped, as
are samples without rmw_zenoh's attachment (``setpoints.without_attachment``).

Run: ``python -m master_slave.slave --device slave --master master --connect tcp/...``.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from master_slave.operator import DEFAULT_SURFACE_Y_M, palpation_start_rad
from master_slave.process_args import (
    RunConfig,
    add_plant_effect_arguments,
    add_process_arguments,
    loop_config_from_args,
    run_config_from_args,
)
from master_slave.realtime import LoopConfig, RateLoop
from master_slave.ros2_outputs import Ros2Outputs
from master_slave.safety import SafetyConfig, SafetyMonitor
from teleop_force.errors import ConfigurationError, MessageError, TeleopForceError
from teleop_force.process.lifetime import (
    StopSignal,
    log,
    use_realtime_switch_interval,
    write_json,
)
from teleop_force.process.memory import MemoryTrimmer
from teleop_force.ros2 import streams
from teleop_force.ros2 import topics as ros2_topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Subscription
from teleop_force.ros2.topics import MEASURED_JS
from teleop_force.simulation import (
    EFFECT_NAMES,
    PID,
    PIDGains,
    PlaneContact,
    PlantConfig,
    PlantEffect,
    SimulatedOmni,
    make_effect,
)
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import (
    declare_json_queryable,
    declare_liveliness_subscriber,
    declare_token,
    undeclare_all,
    wait_for_subscribers,
)
from teleop_force.transport.session import ZenohOptions, open_session, options_from_args
from teleop_force.transport.stream_stats import LatencyHistogram, SequenceTracker

ROLE = "slave"
#: Joints of the Omni: a setpoint for another count is malformed.
JOINTS = 3
STATUS_PERIOD_S = 0.1
SEQ_MASK = 0xFFFF_FFFF
#: A setpoint in the model's coordinates: names empty or the model's, three joints.
_DECODE_SETPOINT = streams.decoder(ros2_topics.SETPOINT_JS, JOINTS)
#: Hold events kept for the statistics (the oldest are dropped; all are counted).
HOLD_EVENTS_KEPT = 20


@dataclass(frozen=True)
class EffectSwitch:
    """A simulated plant effect switched on mid-session (the residual watch's check).

    At ``at_s`` seconds of the slave's loop, :func:`make_effect` ``name`` is switched on in the
    plant on ``joint`` (0-based; ``None``: the effect's default joint) with the strength that
    makes its RMS over the last :data:`CALIBRATION_S` seconds ``scale`` times the joint's RMS
    commanded torque over the session so far (:func:`calibrated_effect`).
    """

    name: str
    at_s: float = 60.0
    scale: float = 0.1
    joint: int | None = None

    def __post_init__(self) -> None:
        """Check the name and ranges; raise ConfigurationError."""
        if self.name not in EFFECT_NAMES:
            raise ConfigurationError(
                f"unknown plant effect {self.name!r}; known: {', '.join(EFFECT_NAMES)}"
            )
        if not (math.isfinite(self.at_s) and self.at_s >= 0.0):
            raise ConfigurationError(f"the effect's switch-on time must be >= 0, got {self.at_s}")
        if not (math.isfinite(self.scale) and self.scale > 0.0):
            raise ConfigurationError(f"the effect's scale must be > 0, got {self.scale}")
        if self.joint is not None and not 0 <= self.joint < JOINTS:
            raise ConfigurationError(f"the effect's joint must be 1..{JOINTS}")


#: History the effect's strength is calibrated on [s].
CALIBRATION_S = 10.0


def calibrated_effect(
    switch: EffectSwitch,
    t_now_s: float,
    rms_torque_nm: np.ndarray,
    q_rad: np.ndarray,
    qd_rad_s: np.ndarray,
    tau_nm: np.ndarray,
) -> PlantEffect:
    """Return the effect of ``switch`` whose RMS on the history is ``scale`` x the RMS torque.

    Every built-in effect is linear in its strength: the unit-strength effect is evaluated on
    the history ``(q, qd, tau)`` (N, 3) at time ``t_now_s`` and scaled. ``rms_torque_nm``: the
    joints' RMS commanded torque.
    """
    unit = make_effect(switch.name, switch.joint, 1.0)
    t = np.full(q_rad.shape[0], float(t_now_s))
    torque = unit.torque(t, q_rad, qd_rad_s, tau_nm)[:, unit.joint]
    unit_rms = float(np.sqrt(np.mean(torque * torque))) if torque.size else 0.0
    if not unit_rms > 0.0:
        raise ConfigurationError(f"{switch.name}: zero on the history, cannot calibrate it")
    strength = switch.scale * float(rms_torque_nm[unit.joint]) / unit_rms
    return make_effect(switch.name, unit.joint, strength)


class _EffectHistory:
    """What the slave keeps to calibrate an effect: running sums and the last seconds."""

    def __init__(self, samples: int) -> None:
        self.sum_sq = np.zeros(JOINTS)
        self.count = 0
        self.q = np.zeros((samples, JOINTS))
        self.qd = np.zeros((samples, JOINTS))
        self.tau = np.zeros((samples, JOINTS))
        self.size = samples

    def add(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> None:
        i = self.count % self.size
        self.q[i], self.qd[i], self.tau[i] = q, qd, tau
        self.sum_sq += tau * tau
        self.count += 1

    def rms_torque_nm(self) -> np.ndarray:
        return np.sqrt(self.sum_sq / max(self.count, 1))

    def window(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        k = min(self.count, self.size)
        return self.q[:k], self.qd[:k], self.tau[:k]


@dataclass(frozen=True)
class SlaveConfig:
    """Settings of the slave process.

    Attributes:
        device: Device id of the slave.
        master: Device id of the master it follows.
        loop: Control-loop timing.
        run: Duration, start handshake, statistics output.
        safety: Staleness threshold and resume rule.
        max_speed_rad_s: Slew-rate limit of the followed setpoint per joint.
        hold_damping_nms_per_rad: Extra joint damping while holding.
        surface_y_m: Height of the tissue surface (``None``: no tissue).
        seed: Seed of the plant's actuator noise.
        effect_switch: A plant effect switched on mid-session (``None``: none).

    """

    device: str = "slave"
    master: str = "master"
    loop: LoopConfig = field(default_factory=LoopConfig)
    run: RunConfig = field(default_factory=RunConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    max_speed_rad_s: float = 2.0
    hold_damping_nms_per_rad: tuple[float, float, float] = (0.06, 0.07, 0.03)
    surface_y_m: float | None = DEFAULT_SURFACE_Y_M
    seed: int = 1
    effect_switch: EffectSwitch | None = None

    def __post_init__(self) -> None:
        """Validate the ids and ranges."""
        keys.validate_chunk(self.device)
        keys.validate_chunk(self.master)
        if not (math.isfinite(self.max_speed_rad_s) and self.max_speed_rad_s > 0.0):
            raise ConfigurationError(f"max_speed_rad_s must be > 0, got {self.max_speed_rad_s}")
        damping = tuple(float(x) for x in self.hold_damping_nms_per_rad)
        if len(damping) != 3 or any(not (math.isfinite(x) and x >= 0.0) for x in damping):
            raise ConfigurationError("hold_damping_nms_per_rad needs 3 values >= 0")
        object.__setattr__(self, "hold_damping_nms_per_rad", damping)
        if self.seed < 0:
            raise ConfigurationError(f"seed must be >= 0, got {self.seed}")


def slew_toward(current: Sequence[float], target: Sequence[float], max_step: float) -> list[float]:
    """Move each joint of ``current`` toward ``target`` by at most ``max_step`` [rad]."""
    moved = []
    for c, t in zip(current, target, strict=True):
        d = t - c
        moved.append(c + (max_step if d > max_step else (-max_step if d < -max_step else d)))
    return moved


class SetpointInbox:
    """The latest valid setpoint from the master, written by the Zenoh callback thread.

    The control loop reads :meth:`latest` every tick without a lock: the callback replaces
    one tuple ``(q, arrival, count)`` in a single (atomic) assignment.
    """

    def __init__(self) -> None:
        """Start empty."""
        self._lock = threading.Lock()
        self._latest: tuple[tuple[float, ...] | None, float | None, int] = (None, None, 0)
        self.count = 0
        self.malformed = 0
        self.last_malformed = ""
        self.seqs = SequenceTracker()
        self.latency = LatencyHistogram()

    def on_sample(self, payload: bytes, attachment: Attachment) -> None:
        """rmw_zenoh callback: a JointState setpoint in the model's coordinates.

        Its loss is counted from the attachment's sequence number, its latency from the
        attachment's source time.
        """
        arrival_ns = time.time_ns()
        arrival_s = time.perf_counter()
        try:
            msg = _DECODE_SETPOINT(payload, attachment.sequence_number & SEQ_MASK)
        except MessageError as exc:
            self._count_malformed(exc)
            return
        self._keep(msg.seq, attachment.source_timestamp_ns, msg.q_rad, arrival_ns, arrival_s)

    def _count_malformed(self, exc: MessageError) -> None:
        with self._lock:
            self.malformed += 1
            self.last_malformed = str(exc)

    def _keep(
        self, seq: int, t_ns: int, q: tuple[float, ...], arrival_ns: int, arrival_s: float
    ) -> None:
        with self._lock:
            self.seqs.observe(seq)
            self.latency.add((arrival_ns - t_ns) * 1e-9)
            self.count += 1
            self._latest = (q, arrival_s, self.count)

    def latest(self) -> tuple[tuple[float, ...] | None, float | None, int]:
        """``(q [rad], arrival time [perf_counter s], number received)``."""
        return self._latest

    def stats(self) -> dict[str, Any]:
        """Counters and the setpoint latency (master stamp -> arrival here) [ms]."""
        with self._lock:
            return {
                **self.seqs.to_dict(),
                "valid": self.count,
                "malformed": self.malformed,
                "last_malformed": self.last_malformed,
                "latency_ms": self.latency.summary_ms(),
            }


class MasterPresence:
    """Whether the master's liveliness token is present (liveliness subscriber callback)."""

    def __init__(self) -> None:
        """Not present until a token is reported."""
        self.alive = False
        self.changes = 0
        self.lost_at_s: float | None = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh liveliness callback."""
        alive = sample.kind == zenoh.SampleKind.PUT
        if alive != self.alive:
            self.changes += 1
        if not alive:
            self.lost_at_s = time.perf_counter()
        self.alive = alive


class SlaveProcess:
    """The slave's plant, controller, safety monitor and Zenoh entities."""

    def __init__(self, config: SlaveConfig, options: ZenohOptions, stop: StopSignal) -> None:
        """Build the plant; nothing is opened until :meth:`run`."""
        self.config = config
        self.options = options
        self.stop = stop
        contact = (
            None if config.surface_y_m is None else PlaneContact.horizontal(config.surface_y_m)
        )
        surface = DEFAULT_SURFACE_Y_M if config.surface_y_m is None else config.surface_y_m
        self.plant = SimulatedOmni(
            PlantConfig(control_period_s=config.loop.period_s),
            seed=config.seed,
            contact=contact,
            q0_rad=palpation_start_rad(surface),
        )
        self.pid = PID(PIDGains.omni(), n_joints=3, control_period_s=config.loop.period_s)
        self.pid.reset(integral_nm=self.plant.holding_torque_nm())
        self.loop = RateLoop(config.loop)
        self.safety = SafetyMonitor(config.safety)
        self.inbox = SetpointInbox()
        self.presence = MasterPresence()
        self.published = 0
        #: Time spent publishing a joint state (congestion control BLOCK waits here).
        self.put_time = LatencyHistogram()
        #: The last HOLD_EVENTS_KEPT hold events (bounded: a long run with many holds
        #: cannot grow it); ``hold_events_total`` counts them all.
        self.hold_events: deque[dict[str, Any]] = deque(maxlen=HOLD_EVENTS_KEPT)
        self.hold_events_total = 0
        self._status_seq = 0
        self._last_status_s = -math.inf
        self._ros2: Ros2Outputs | None = None
        #: The setpoint subscription (it counts samples dropped for a missing attachment).
        self._setpoints: Subscription | None = None
        #: The plant effect switched on mid-session, once it is (``effect``, ``at_s``).
        self.switched_effect: dict[str, Any] | None = None

    # -- statistics ---------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        """JSON statistics of the process (also the reply of the stats queryable)."""
        return {
            "role": ROLE,
            "device": self.config.device,
            "master": self.config.master,
            "state": self.safety.state.name.lower(),
            "reason": self.safety.reason,
            "loop": self.loop.stats(),
            "setpoints": {
                **self.inbox.stats(),
                "without_attachment": 0 if self._setpoints is None else self._setpoints.malformed,
            },
            "published_joint_states": self.published,
            "joint_state_put_ms": self.put_time.summary_ms(),
            "master_alive": self.presence.alive,
            "holds": self.safety.holds,
            "hold_events": list(self.hold_events.copy()),  # copy: atomic against the loop
            "hold_events_total": self.hold_events_total,
            "torque_clips": self.plant.clip_count,
            "plant_effect": self.switched_effect,
        }

    # -- main loop ----------------------------------------------------------------------------

    def run(self) -> dict[str, Any]:
        """Open Zenoh, run the control loop until stopped, clean up; return the final stats."""
        config = self.config
        session = open_session(self.options)
        entities: list[Any] = []
        try:
            ros2 = self._ros2 = Ros2Outputs(
                session, ROLE, config.device,
                (ros2_topics.MEASURED_JS, ros2_topics.TRUE_CF, ros2_topics.STATUS),
                followed=(ros2_topics.MEASURED_JS,),  # the true force comes next, each tick
            )  # fmt: skip
            self._setpoints = ros2.node.subscription(
                ros2_topics.topic_name(config.master, ros2_topics.SETPOINT_JS),
                ros2_topics.SETPOINT_JS.ros_type,
                self.inbox.on_sample,
                direct=True,  # on Zenoh's receive thread: no hand-over to a Python thread
            )
            entities.append(
                declare_liveliness_subscriber(
                    session, keys.alive(config.master, "master"), self.presence.on_sample
                )
            )
            entities.append(
                declare_json_queryable(session, keys.process_stats(config.device, ROLE), self.stats)
            )
            entities.append(declare_token(session, keys.alive(config.device, ROLE)))
            if config.run.wait_subscribers_s > 0.0:
                # The master too (its token): a peer joining while the loop runs holds up
                # the loop's puts for tens of milliseconds (Zenoh updates its routes).
                matched = wait_for_subscribers(
                    ros2.zenoh_publisher(MEASURED_JS),
                    config.run.wait_subscribers_s,
                    stop=self.stop.is_set,
                    ready=lambda: self.presence.alive,
                )
                if not matched and not self.stop.is_set():
                    log(
                        ROLE, "no subscriber for the joint states or no master yet; starting anyway"
                    )
            self._publish_status(time.perf_counter(), force=True)
            log(
                ROLE,
                f"{config.device} running at {config.loop.rate_hz:g} Hz, following {config.master}",
            )
            self._control_loop(ros2)
            self.safety.stop("slave stopped")
            self._publish_status(time.perf_counter(), force=True)
        finally:
            outputs, self._ros2 = self._ros2, None
            if outputs is not None:
                outputs.close()
            undeclare_all(*reversed(entities))
            self.plant.close()
            session.close()
        return self.stats()

    def _control_loop(self, ros2: Ros2Outputs) -> None:
        config = self.config
        plant, pid, loop, safety, inbox = self.plant, self.pid, self.loop, self.safety, self.inbox
        presence, put_time, stop = self.presence, self.put_time, self.stop
        n_ticks = (
            None
            if config.run.duration_s is None
            else round(config.run.duration_s * config.loop.rate_hz)
        )
        max_step = config.max_speed_rad_s * config.loop.period_s
        damping = np.array(config.hold_damping_nms_per_rad)
        no_force = (0.0, 0.0, 0.0)
        # The followed (slew-limited) reference as plain floats: three joints are cheaper
        # in Python than in numpy.
        q_ref = plant.measured_q_rad().tolist()
        following = m.SafetyState.FOLLOWING
        perf_counter = time.perf_counter
        switch = config.effect_switch
        history = (
            None if switch is None else _EffectHistory(round(CALIBRATION_S * config.loop.rate_hz))
        )
        switch_tick = None if switch is None else round(switch.at_s * config.loop.rate_hz)
        loop.start()
        while not stop.is_set():
            k = loop.wait()
            if n_ticks is not None and k >= n_ticks:
                break
            stamp_ns = loop.stamp_ns
            state = plant.read()
            q = state.q_rad
            q_sp, arrival_s, count = inbox.latest()
            now_s = perf_counter()
            decision = safety.update(now_s, presence.alive, arrival_s, count)
            is_following = decision.state == following
            if decision.changed:
                if not is_following:
                    q_ref = q.tolist()  # hold where the arm is
                    self._record_hold(now_s, arrival_s, decision.reason)
                self._publish_status(now_s, force=True)
            if is_following and q_sp is not None:
                q_ref = slew_toward(q_ref, q_sp, max_step)
            tau = pid.update(np.array(q_ref), q)
            if not is_following:
                tau = tau - damping * pid.velocity_rad_s
            command = plant.command_torque(tau)
            if history is not None:
                history.add(q, pid.velocity_rad_s, command.tau_nm)
                if switch_tick is not None and k >= switch_tick:  # ticks may be skipped
                    self._switch_effect(history, k * config.loop.period_s)
                    switch_tick = None
            q_l, qd_l, tau_l = q.tolist(), pid.velocity_rad_s.tolist(), command.tau_nm.tolist()
            put_started_s = perf_counter()
            ros2.joint_state(stamp_ns, q_l, qd_l, tau_l)
            put_time.add(perf_counter() - put_started_s)
            force = state.f_tip_in_base_n
            ros2.true_force(stamp_ns, no_force if force is None else force.tolist())
            self.published += 1
            if now_s - self._last_status_s >= STATUS_PERIOD_S:
                self._publish_status(now_s)
            plant.step()

    def _switch_effect(self, history: _EffectHistory, t_s: float) -> None:
        """Switch the configured plant effect on, calibrated on the history (EffectSwitch)."""
        switch = self.config.effect_switch
        assert switch is not None
        q, qd, tau = history.window()
        try:
            effect = calibrated_effect(switch, self.plant.t_s, history.rms_torque_nm(), q, qd, tau)
        except ConfigurationError as exc:
            log(ROLE, f"plant effect not switched on: {exc}")
            return
        self.plant.effects = (*self.plant.effects, effect)
        self.switched_effect = {"effect": effect.describe(), "at_s": round(t_s, 3)}
        log(ROLE, f"plant effect switched on at {t_s:.1f} s: {effect.describe()}")

    def _record_hold(self, now_s: float, arrival_s: float | None, reason: str) -> None:
        event: dict[str, Any] = {"tick": self.loop.tick, "reason": reason}
        if arrival_s is not None:
            event["setpoint_age_ms"] = round((now_s - arrival_s) * 1e3, 3)
        if self.presence.lost_at_s is not None and not self.presence.alive:
            event["since_token_lost_ms"] = round((now_s - self.presence.lost_at_s) * 1e3, 3)
        self.hold_events.append(event)
        self.hold_events_total += 1
        if self.safety.state == m.SafetyState.HOLDING:
            log(ROLE, f"HOLDING: {reason}")

    def _publish_status(self, now_s: float, force: bool = False) -> None:
        if self._ros2 is None or (not force and now_s - self._last_status_s < STATUS_PERIOD_S):
            return
        status = m.Status(self._status_seq, time.time_ns(), self.safety.state, self.safety.reason)
        self._ros2.status(status)
        self._status_seq += 1
        self._last_status_s = now_s


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``python -m master_slave.slave``."""
    parser = argparse.ArgumentParser(
        prog="python -m master_slave.slave", description=__doc__.splitlines()[0]
    )
    add_process_arguments(parser, device="slave", wait_subscribers_s=0.0)
    parser.add_argument(
        "--master", default="master", help="device id of the master (default master)"
    )
    parser.add_argument(
        "--stale-ms",
        type=float,
        default=50.0,
        help="hold when the last setpoint is older (default 50)",
    )
    parser.add_argument(
        "--max-speed", type=float, default=2.0, help="setpoint slew limit [rad/s] (default 2)"
    )
    parser.add_argument(
        "--surface-y", type=float, default=DEFAULT_SURFACE_Y_M, help="tissue surface height [m]"
    )
    parser.add_argument("--no-tissue", action="store_true", help="no soft tissue (free space)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the actuator noise")
    add_plant_effect_arguments(parser)
    return parser


def compile_plant_kernels(model_path: Path | None = None) -> None:
    """Compile (or load) the slave's and master's kernels here (``teleop_force.process.warm_up``).

    Building them is enough: their plant and PID compile their kernels as they are built. One
    process for both: the plants share most kernels, compiled once.
    """
    from master_slave.master import MasterConfig, MasterProcess

    SlaveProcess(SlaveConfig(), ZenohOptions(), StopSignal())
    MasterProcess(MasterConfig(), ZenohOptions(), StopSignal())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the slave process; return the exit status."""
    args = build_parser().parse_args(argv)
    stop = StopSignal().install().watch_supervisor()
    use_realtime_switch_interval()
    try:
        config = SlaveConfig(
            device=args.device,
            master=args.master,
            loop=loop_config_from_args(args),
            run=run_config_from_args(args),
            safety=SafetyConfig(stale_s=args.stale_ms * 1e-3),
            max_speed_rad_s=args.max_speed,
            surface_y_m=None if args.no_tissue else args.surface_y,
            seed=args.seed,
            effect_switch=(
                None
                if args.plant_effect is None
                else EffectSwitch(
                    args.plant_effect,
                    args.plant_effect_at_s,
                    args.plant_effect_scale,
                    None if args.plant_effect_joint is None else args.plant_effect_joint - 1,
                )
            ),
        )
        with MemoryTrimmer() as trimmer:  # a long-running process: RSS follows what is live
            stats = SlaveProcess(config, options_from_args(args), stop).run()
        stats["memory"] = trimmer.stats()
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    if config.run.stats_json:
        write_json(config.run.stats_json, stats)
    loop_stats = stats["loop"]
    log(
        ROLE,
        f"stopped after {loop_stats['ticks']} ticks: overruns {loop_stats['overruns']}, "
        f"setpoints lost {stats['setpoints']['lost']}, malformed {stats['setpoints']['malformed']}",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
