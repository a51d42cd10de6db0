"""The master Omni process: the operator's arm, whose pose the slave follows.

The master is a :class:`~teleop_force.robots.device.Device` (here a :class:`SimulatedOmni` without a
tissue; a real Omni driver would replace it). A simulated operator's hand holds its stylus and
moves it along a script (:mod:`master_slave.operator`: palpation or random motion): the hand
is a stiff PID impedance on the master's joints, whose torque the plant receives together
with the master's own motor torque. Every 1 ms tick::

    read the master (measured q), stamped with the wall time of the reading
    publish the pose q on /<master>/setpoint_js (a JointState)   (what the slave follows)
    hand torque toward the script; haptic feedback torque J(q)^T (-scale F_est) if enabled
    publish JointState (q, qd, effort = the master's motor torque = the feedback)
    step the plant

Haptic feedback (``--haptic-feedback``): the estimated force of the slave's tip on the tissue
``F`` (``/<slave>/estimated_cf``, a WrenchStamped) is displayed to the operator as
``-scale F``, clipped to the Omni's 3.3 N and to the motor torque limit; it is switched off
when the estimate is older than 50 ms or not a number.

Run: ``python -m master_slave.master --device master --connect tcp/...``.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from master_slave.operator import (
    DEFAULT_SURFACE_Y_M,
    MOTIONS,
    OperatorConfig,
    ScriptedOperator,
)
from master_slave.process_args import (
    RunConfig,
    add_process_arguments,
    loop_config_from_args,
    run_config_from_args,
)
from master_slave.realtime import LoopConfig, RateLoop
from master_slave.ros2_outputs import Ros2Outputs
from teleop_force.errors import ConfigurationError, MessageError, TeleopForceError
from teleop_force.process.lifetime import (
    StopSignal,
    log,
    use_realtime_switch_interval,
    write_json,
)
from teleop_force.process.memory import MemoryTrimmer
from teleop_force.robots import omni
from teleop_force.ros2 import codec, fast_cdr
from teleop_force.ros2 import topics as ros2_topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.topics import SETPOINT_JS
from teleop_force.simulation import PID, PIDGains, PlantConfig, SimulatedOmni
from teleop_force.transport import keys
from teleop_force.transport.pubsub import (
    declare_json_queryable,
    declare_liveliness_subscriber,
    declare_token,
    undeclare_all,
    wait_for_subscribers,
)
from teleop_force.transport.session import ZenohOptions, open_session, options_from_args
from teleop_force.transport.stream_stats import LatencyHistogram, SequenceTracker

ROLE = "master"
#: Joints of the Omni: an estimate for another count is malformed.
JOINTS = 3
SEQ_MASK = 0xFFFF_FFFF
#: The hand and the motors together may exceed one motor's limit (the hand is not a motor).
HAND_PLUS_MOTOR_LIMIT_NM = 3.0
#: Feedback older than this is not displayed [s].
FEEDBACK_STALE_S = 0.05
_WRENCH = fast_cdr.WrenchLayout(ros2_topics.BASE_FRAME)


@dataclass(frozen=True)
class MasterConfig:
    """Settings of the master process.

    Attributes:
        device: Device id of the master.
        slave: Device id of the slave whose estimated force is fed back.
        loop: Control-loop timing.
        run: Duration, start handshake, statistics output.
        operator: The simulated operator's script.
        haptic_feedback: Display the estimated force to the operator.
        feedback_scale: Force scaling of the feedback (0..1).
        substeps: Integration sub-steps of the master plant per tick (no contact: 1 is enough).
        seed: Seed of the master plant's actuator noise.

    """

    device: str = "master"
    slave: str = "slave"
    loop: LoopConfig = field(default_factory=LoopConfig)
    run: RunConfig = field(default_factory=RunConfig)
    operator: OperatorConfig = field(default_factory=OperatorConfig)
    haptic_feedback: bool = False
    feedback_scale: float = 0.5
    substeps: int = 1
    seed: int = 2

    def __post_init__(self) -> None:
        """Validate the ids and ranges."""
        keys.validate_chunk(self.device)
        keys.validate_chunk(self.slave)
        if not (math.isfinite(self.feedback_scale) and 0.0 <= self.feedback_scale <= 1.0):
            raise ConfigurationError(f"feedback_scale must be in [0, 1], got {self.feedback_scale}")
        if self.substeps < 1 or self.seed < 0:
            raise ConfigurationError("substeps must be >= 1 and seed >= 0")


class FeedbackInbox:
    """The latest estimated force of the slave (Zenoh callback thread writes it)."""

    def __init__(self) -> None:
        """Start empty."""
        self._lock = threading.Lock()
        self.force_n = np.zeros(3)
        self.arrival_s: float | None = None
        self.malformed = 0
        self.seqs = SequenceTracker()
        self.latency = LatencyHistogram()

    def on_sample(self, payload: bytes, attachment: Attachment) -> None:
        """rmw_zenoh callback: a WrenchStamped; seq and latency from the attachment."""
        arrival_ns = time.time_ns()
        try:
            fast = _WRENCH.unpack(payload)  # one struct call; another layout through rosbags
            f_n = codec.decode_wrench(payload).force_n if fast is None else fast[1]
        except MessageError:
            with self._lock:
                self.malformed += 1
            return
        seq = attachment.sequence_number & SEQ_MASK
        self._keep(seq, attachment.source_timestamp_ns, f_n, arrival_ns)

    def _keep(self, seq: int, t_ns: int, f_n: Sequence[float], arrival_ns: int) -> None:
        force = np.array(f_n)
        with self._lock:
            self.seqs.observe(seq)
            self.latency.add((arrival_ns - t_ns) * 1e-9)
            self.force_n = force
            self.arrival_s = time.perf_counter()

    def latest(self) -> tuple[np.ndarray, float | None]:
        """``(force [N], arrival time [perf_counter s])``."""
        with self._lock:
            return self.force_n, self.arrival_s

    def stats(self) -> dict[str, Any]:
        """Counters and latency (estimate publish -> arrival here) [ms]."""
        with self._lock:
            return {
                **self.seqs.to_dict(),
                "malformed": self.malformed,
                "latency_ms": self.latency.summary_ms(),
            }


def feedback_torque_nm(
    q_rad: np.ndarray, force_n: np.ndarray, scale: float, limit_nm: float
) -> np.ndarray:
    """Motor torque ``J(q)^T (-scale F)`` displaying the environment's reaction, clipped."""
    if not np.all(np.isfinite(force_n)):
        return np.zeros(3)
    display = -scale * force_n
    norm = float(np.linalg.norm(display))
    if norm > omni.TIP_FORCE_LIMIT_N:
        display *= omni.TIP_FORCE_LIMIT_N / norm
    tau = omni.tip_jacobian_formula(q_rad).T @ display
    return np.clip(tau, -limit_nm, limit_nm)


class MasterProcess:
    """The master's plant, the operator and the Zenoh entities."""

    def __init__(self, config: MasterConfig, options: ZenohOptions, stop: StopSignal) -> None:
        """Build the plant at the script's start; nothing is opened until :meth:`run`."""
        self.config = config
        self.options = options
        self.stop = stop
        self.operator = ScriptedOperator(config.operator, config.loop.period_s)
        self.plant = SimulatedOmni(
            PlantConfig(
                control_period_s=config.loop.period_s,
                substeps=config.substeps,
                torque_limit_nm=HAND_PLUS_MOTOR_LIMIT_NM,
            ),
            seed=config.seed,
            q0_rad=self.operator.start_rad(),
        )
        self.hand = PID(PIDGains.omni(), n_joints=3, control_period_s=config.loop.period_s)
        self.hand.reset(integral_nm=self.plant.holding_torque_nm())
        self.loop = RateLoop(config.loop)
        self.feedback = FeedbackInbox()
        self.published = 0
        self._ros2: Ros2Outputs | None = None
        self.waited_for_subscriber_s = 0.0
        #: Time spent publishing a setpoint (congestion control BLOCK waits here).
        self.put_time = LatencyHistogram()

    def stats(self) -> dict[str, Any]:
        """JSON statistics of the process (also the reply of the stats queryable)."""
        return {
            "role": ROLE,
            "device": self.config.device,
            "motion": self.config.operator.motion,
            "haptic_feedback": self.config.haptic_feedback,
            "loop": self.loop.stats(),
            "published_setpoints": self.published,
            "setpoint_put_ms": self.put_time.summary_ms(),
            "waited_for_subscriber_s": round(self.waited_for_subscriber_s, 3),
            "feedback": self.feedback.stats(),
        }

    def run(self) -> dict[str, Any]:
        """Open Zenoh, run the loop until stopped, clean up; return the final stats."""
        config = self.config
        session = open_session(self.options)
        entities: list[Any] = []
        try:
            ros2 = self._ros2 = Ros2Outputs(
                session, ROLE, config.device, (ros2_topics.MEASURED_JS, ros2_topics.SETPOINT_JS),
                followed=(ros2_topics.SETPOINT_JS,),  # the measured state comes next, each tick
            )  # fmt: skip
            if config.haptic_feedback:
                ros2.node.subscription(
                    ros2_topics.topic_name(config.slave, ros2_topics.ESTIMATED_CF),
                    ros2_topics.ESTIMATED_CF.ros_type,
                    self.feedback.on_sample,
                    direct=True,  # on Zenoh's receive thread: no hand-over per sample
                )
            entities.append(
                declare_json_queryable(session, keys.process_stats(config.device, ROLE), self.stats)
            )
            entities.append(declare_token(session, keys.alive(config.device, ROLE)))
            if config.run.wait_subscribers_s > 0.0:
                # Wait for the slave itself, not just any subscriber (a recorder may subscribe
                # first): its token comes after its setpoint subscriber.
                slave_seen = threading.Event()

                def on_slave_token(sample: zenoh.Sample) -> None:
                    if sample.kind == zenoh.SampleKind.PUT:
                        slave_seen.set()

                entities.append(
                    declare_liveliness_subscriber(
                        session, keys.alive(config.slave, "slave"), on_slave_token
                    )
                )
                started = time.perf_counter()
                matched = wait_for_subscribers(
                    ros2.zenoh_publisher(SETPOINT_JS),
                    config.run.wait_subscribers_s,
                    stop=self.stop.is_set,
                    ready=slave_seen.is_set,
                )
                self.waited_for_subscriber_s = time.perf_counter() - started
                if not matched and not self.stop.is_set():
                    log(ROLE, "no slave subscribed to the setpoints yet; starting anyway")
            log(
                ROLE,
                f"{config.device} running at {config.loop.rate_hz:g} Hz ({config.operator.motion})",
            )
            self._control_loop(ros2)
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
        plant, hand, loop, operator = self.plant, self.hand, self.loop, self.operator
        put_time, stop, feedback = self.put_time, self.stop, self.feedback
        n_ticks = (
            None
            if config.run.duration_s is None
            else round(config.run.duration_s * config.loop.rate_hz)
        )
        feedback_on = config.haptic_feedback
        scale = config.feedback_scale
        no_torque = (0.0, 0.0, 0.0)
        perf_counter, time_ns = time.perf_counter, time.time_ns
        loop.start()
        while not stop.is_set():
            k = loop.wait()
            if n_ticks is not None and k >= n_ticks:
                break
            q = plant.read().q_rad
            stamp_ns = time_ns()  # when the pose was read, as a real driver would stamp it
            q_floats = q.tolist()
            put_started_s = perf_counter()
            ros2.setpoint(stamp_ns, q_floats)
            put_time.add(perf_counter() - put_started_s)
            q_hand, qd_hand = operator.reference(k)
            tau_hand = hand.update(q_hand, q, qd_hand)
            motor: Sequence[float] = no_torque
            if feedback_on:
                force, arrival_s = feedback.latest()
                if arrival_s is not None and perf_counter() - arrival_s <= FEEDBACK_STALE_S:
                    tau_motor = feedback_torque_nm(q, force, scale, omni.MOTOR_TORQUE_LIMIT_NM)
                    tau_hand = tau_hand + tau_motor
                    motor = tau_motor.tolist()
            plant.command_torque(tau_hand)
            qd_floats = hand.velocity_rad_s.tolist()
            ros2.joint_state(stamp_ns, q_floats, qd_floats, motor)
            self.published += 1
            plant.step()


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``python -m master_slave.master``."""
    parser = argparse.ArgumentParser(
        prog="python -m master_slave.master", description=__doc__.splitlines()[0]
    )
    add_process_arguments(parser, device="master", wait_subscribers_s=10.0)
    parser.add_argument("--slave", default="slave", help="device id of the slave (default slave)")
    parser.add_argument("--motion", choices=MOTIONS, default="palpation", help="operator script")
    parser.add_argument("--seed", type=int, default=0, help="seed of the operator's script")
    parser.add_argument(
        "--surface-y",
        type=float,
        default=DEFAULT_SURFACE_Y_M,
        help="height of the slave's tissue the palpation script is written for [m]",
    )
    parser.add_argument(
        "--haptic-feedback", action="store_true", help="display the estimated force on the master"
    )
    parser.add_argument("--feedback-scale", type=float, default=0.5, help="force scaling (0..1)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the master process; return the exit status."""
    args = build_parser().parse_args(argv)
    stop = StopSignal().install().watch_supervisor()
    use_realtime_switch_interval()
    try:
        run = run_config_from_args(args)
        config = MasterConfig(
            device=args.device,
            slave=args.slave,
            loop=loop_config_from_args(args),
            run=run,
            operator=OperatorConfig(
                motion=args.motion,
                seed=args.seed,
                duration_s=run.duration_s,
                surface_y_m=args.surface_y,
            ),
            haptic_feedback=args.haptic_feedback,
            feedback_scale=args.feedback_scale,
        )
        with MemoryTrimmer() as trimmer:  # a long-running process: RSS follows what is live
            stats = MasterProcess(config, options_from_args(args), stop).run()
        stats["memory"] = trimmer.stats()
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    if config.run.stats_json:
        write_json(config.run.stats_json, stats)
    log(
        ROLE,
        f"stopped after {stats['loop']['ticks']} ticks: overruns {stats['loop']['overruns']}",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
