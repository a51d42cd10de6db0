"""The slave-side force-estimation service: joint states in, force estimates out, over Zenoh.

For one device (``--device``, the slave)::

    subscribes  omni/<device>/measured_js     JointState: q and effort = commanded torque
    publishes   omni/<device>/estimated_cf    ForceEstimate, one per joint state
    queryable   omni/<device>/service/model   the model JSON (DynamicModel.to_dict())
    queryable   omni/<device>/service/stats   JSON statistics (below)
    subscribes  omni/<device>/service/adapt   "on" / "off": online WN adaptation
    token       omni/<device>/alive/service

Each joint state is run through :class:`~teleop_force.estimation.ForceEstimator` (streaming,
no accelerations) with the time ``t = (t_ns - t0_ns) * 1e-9`` counted in integer nanoseconds
from the first sample of the stream, so the same stream gives the same floats whenever it is
played (a replay shifted in time included). A stream restarts, and the estimator with it,
when its ``seq`` goes backwards or jumps far, or its stamp goes backwards or pauses > 0.5 s.
The estimate's ``source_seq`` is the joint state's ``seq`` and its ``t_ns`` the time it was
published, so ``t_ns - (joint state t_ns)`` is the slave -> estimate latency.

Statistics (``service/stats``): joint states received / lost (sequence gaps) / restarts /
duplicates, malformed messages dropped (by key), estimates published, singular, latency
p50/p99/max [ms] (joint-state stamp -> estimate publish), processing time, rates, the fraction
of estimates on trained ground, adaptation state, recording.

Recording (``--record PATH``): every joint state (of every device), setpoint, true contact
force and status received, and every estimate published, to an MCAP session
(:class:`~teleop_force.mcap_session.SessionWriter`) whose channels are the Zenoh keys, with
metadata ``primary_device=<device>``.

Run: ``python -m teleop_force.service --device slave --connect tcp/127.0.0.1:7447``.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import zenoh

from teleop_force import keys
from teleop_force import messages as m
from teleop_force.dynamic_model import DynamicModel
from teleop_force.errors import (
    ConfigurationError,
    DataError,
    MessageError,
    TeleopForceError,
)
from teleop_force.estimation import ForceEstimator
from teleop_force.mcap_session import SessionWriter
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.service_adaptation import OnlineAdaptation, adaptation_unavailable_reason
from teleop_force.service_runtime import (
    StopSignal,
    log,
    use_realtime_switch_interval,
    write_json,
)
from teleop_force.service_stats import LatencyHistogram, RateMeter, SequenceTracker
from teleop_force.service_transport import (
    declare_data_publisher,
    declare_json_queryable,
    declare_subscriber,
    declare_token,
    put,
    undeclare_all,
)
from teleop_force.zenoh_session import open_session, options_from_args

ROLE: Final = "service"
SEQ_MASK: Final = 0xFFFF_FFFF
#: A pause longer than this in the joint-state stamps starts a new stream [ns].
MAX_STREAM_PAUSE_NS: Final = 500_000_000
#: Kinds recorded besides the device's own joint states and estimates.
_RECORDED_KINDS: Final = (keys.MEASURED_JS, keys.SETPOINT_JS, keys.MEASURED_CF, keys.STATUS)


@dataclass(frozen=True)
class ServiceConfig:
    """Settings of :class:`ForceService`.

    Attributes:
        device: Device whose joint states are estimated on.
        master: Device id of the master (recorded in the metadata only).
        record_path: MCAP session to record to (``None``: no recording).
        adapt: Start with online adaptation on (needs a WN friction).
        source: ``live`` or ``replay`` (recorded in the metadata).

    """

    device: str = "slave"
    master: str | None = "master"
    record_path: Path | None = None
    adapt: bool = False
    source: str = "live"

    def __post_init__(self) -> None:
        """Validate the device ids."""
        keys.validate_chunk(self.device)
        if self.master is not None:
            keys.validate_chunk(self.master, "master device id")
        if self.record_path is not None:
            object.__setattr__(self, "record_path", Path(self.record_path))
        if self.source not in ("live", "replay"):
            raise ConfigurationError(f"source must be live or replay, got {self.source!r}")


class ForceService:
    """Streaming force estimation of one device on a Zenoh session (module docstring)."""

    def __init__(
        self,
        session: zenoh.Session,
        model: DynamicModel,
        config: ServiceConfig | None = None,
        *,
        model_path: Path | None = None,
    ) -> None:
        """Prepare the estimator (and the recording file); call :meth:`start` to go live."""
        self.session = session
        self.model = model
        self.config = config if config is not None else ServiceConfig()
        self.model_path = model_path
        self.estimator = ForceEstimator(model)
        self.n_joints = model.n_joints
        self._lock = threading.Lock()
        self._closed = False
        self._entities: list[Any] = []
        self._publisher: zenoh.Publisher | None = None
        self._own_js_key = keys.measured_js(self.config.device)
        self._estimate_key = keys.estimated_cf(self.config.device)
        self._t0_ns: int | None = None
        self._last_t_ns: int | None = None
        self._seq = 0
        self._started_s = time.perf_counter()
        self.seqs = SequenceTracker()
        self.latency = LatencyHistogram()
        self.processing = LatencyHistogram()
        self.rate = RateMeter()
        self.published = 0
        self.singular = 0
        self.estimate_errors = 0
        self.last_error = ""
        self.malformed_by_key: dict[str, int] = {}
        self.last_malformed = ""
        self.on_ground_all = 0
        self.on_ground_joint = np.zeros(self.n_joints, dtype=np.int64)
        self.stream_restarts = 0
        self.last_estimate: m.ForceEstimate | None = None
        self.adaptation: OnlineAdaptation | None = None
        self.adapting = False
        self.adaptation_note = adaptation_unavailable_reason(self.estimator) or ""
        self.writer: SessionWriter | None = None
        if self.config.adapt:
            self.set_adaptation(True)
        if self.config.record_path is not None:
            self.writer = self._open_writer(self.config.record_path)

    # -- lifetime -----------------------------------------------------------------------------

    def _open_writer(self, path: Path) -> SessionWriter:
        path.parent.mkdir(parents=True, exist_ok=True)
        metadata = {
            "primary_device": self.config.device,
            "source": self.config.source,
            "robot": self.model.robot,
            "friction": self.model.friction.kind,
            "model": str(self.model_path) if self.model_path is not None else "",
            "recorder": "teleop_force.service",
        }
        if self.config.master is not None:
            metadata["master_device"] = self.config.master
        return SessionWriter(path, metadata)

    def start(self) -> ForceService:
        """Declare the publisher, subscribers, queryables and token; return self."""
        device = self.config.device
        session = self.session
        self._publisher = declare_data_publisher(session, self._estimate_key)
        self._entities.append(self._publisher)
        if self.writer is not None:
            for kind in _RECORDED_KINDS:
                self._entities.append(
                    declare_subscriber(session, keys.any_device(kind), self._on_sample)
                )
        else:
            self._entities.append(declare_subscriber(session, self._own_js_key, self._on_sample))
        self._entities.append(
            declare_subscriber(session, keys.service_adapt(device), self._on_adapt)
        )
        self._entities.append(
            declare_json_queryable(session, keys.service_model(device), self.model_dict)
        )
        self._entities.append(
            declare_json_queryable(session, keys.service_stats(device), self.stats)
        )
        self._entities.append(declare_token(session, keys.alive(device, ROLE)))
        self._started_s = time.perf_counter()
        return self

    def close(self) -> None:
        """Stop processing, undeclare everything, then close the recording (idempotent).

        Callbacks estimate and publish only under the lock and only while not closed, so once
        ``_closed`` is set no callback touches the publisher any more (a publisher must not be
        undeclared while another thread publishes on it). Recording happens outside the lock;
        the writer refuses writes once closed, which the callbacks then ignore.
        """
        with self._lock:
            already = self._closed
            self._closed = True
        entities, self._entities = self._entities, []
        undeclare_all(*reversed(entities))
        if not already and self.writer is not None:
            with self._lock:
                self.writer.close()

    def __enter__(self) -> ForceService:
        """Start the service."""
        return self.start()

    def __exit__(self, *exc: object) -> None:
        """Close the service."""
        self.close()

    # -- callbacks ----------------------------------------------------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Every subscribed data key: estimate on the device's joint states, record the rest."""
        arrival_ns = time.time_ns()
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        if key == self._own_js_key:
            self._on_joint_state(key, payload, arrival_ns)
            return
        try:
            message = m.decode(payload)
        except MessageError as exc:
            self._count_malformed(key, exc)
            return
        self._record(key, message, arrival_ns)

    def _record(self, key: str, message: m.Message, log_time_ns: int) -> None:
        """Write one message to the recording (outside the processing lock)."""
        if self.writer is None or self._closed:
            return
        try:
            self.writer.write(key, message, log_time_ns)
        except DataError as exc:  # e.g. a JointState on a status key, or closed meanwhile
            if not self._closed:
                self._count_malformed(key, exc)

    def _count_malformed(self, key: str, exc: Exception) -> None:
        with self._lock:
            self._count_malformed_locked(key, exc)

    def _count_malformed_locked(self, key: str, exc: Exception) -> None:
        self.malformed_by_key[key] = self.malformed_by_key.get(key, 0) + 1
        self.last_malformed = f"{key}: {exc}"

    def _on_joint_state(self, key: str, payload: bytes, arrival_ns: int) -> None:
        try:
            js = m.JointState.decode(payload)
            if js.n_joints != self.n_joints:
                raise MessageError(f"{js.n_joints} joints, the model has {self.n_joints}")
        except MessageError as exc:
            self._count_malformed(key, exc)
            return
        with self._lock:
            if self._closed:
                return
            estimate = self._estimate_locked(js)
        # Recorded after the estimate is out: the recording does not delay it.
        self._record(key, js, arrival_ns)
        if estimate is not None:
            self._record(self._estimate_key, estimate, estimate.t_ns)

    def _estimate_locked(self, js: m.JointState) -> m.ForceEstimate | None:
        """Estimate on one joint state and publish; return the published message."""
        started_s = time.perf_counter()
        event = self.seqs.observe(js.seq)
        if event.duplicate:
            return None
        self.rate.tick()
        last = self._last_t_ns
        if (
            self._t0_ns is None
            or event.restarted
            or (last is not None and (js.t_ns <= last or js.t_ns - last > MAX_STREAM_PAUSE_NS))
        ):
            if self._t0_ns is not None:
                self.stream_restarts += 1
            self.estimator.reset()
            if self.adaptation is not None:
                self.adaptation.reset()
            self._t0_ns = js.t_ns
        self._last_t_ns = js.t_ns
        t_s = (js.t_ns - self._t0_ns) * 1e-9
        q = np.array(js.q_rad)
        tau = np.array(js.effort_nm)
        try:
            estimate = self.estimator.update(t_s, q, tau)
            if self.adapting and self.adaptation is not None:
                self.adaptation.update(t_s, q, tau)
            message = m.ForceEstimate(
                self._seq,
                time.time_ns(),
                js.seq,
                estimate.force_tip_in_base_n,
                estimate.tau_external_nm,
                estimate.on_trained_ground,
                estimate.coverage_weight,
                estimate.tau_motor_filtered_nm,
                estimate.tau_model_filtered_nm,
            )
        except (DataError, MessageError) as exc:
            self.estimate_errors += 1
            self.last_error = str(exc)
            return None
        assert self._publisher is not None
        put(self._publisher, message.encode())
        self._seq = (self._seq + 1) & SEQ_MASK
        self.published += 1
        self.latency.add((time.time_ns() - js.t_ns) * 1e-9)
        if estimate.singular:
            self.singular += 1
        flags = estimate.on_trained_ground
        self.on_ground_joint += flags
        if bool(np.all(flags)):
            self.on_ground_all += 1
        self.last_estimate = message
        self.processing.add(time.perf_counter() - started_s)
        return message

    def _on_adapt(self, sample: zenoh.Sample) -> None:
        """``service/adapt`` control: payload ``on`` or ``off``."""
        try:
            text = sample.payload.to_string().strip().lower()
        except (UnicodeDecodeError, ValueError) as exc:
            self._count_malformed(str(sample.key_expr), exc)
            return
        if text not in ("on", "off"):
            self._count_malformed(
                str(sample.key_expr), ValueError(f"expected on/off, got {text!r}")
            )
            return
        try:
            self.set_adaptation(text == "on")
        except ConfigurationError as exc:
            log(ROLE, f"adaptation not switched on: {exc}")

    # -- control and reporting ----------------------------------------------------------------

    def set_adaptation(self, on: bool) -> None:
        """Switch online adaptation on or off; raise ConfigurationError if impossible."""
        with self._lock:
            if not on:
                self.adapting = False
                return
            if self.adaptation is None:
                self.adaptation = OnlineAdaptation(self.estimator)
            self.adapting = True

    def model_dict(self) -> dict[str, Any]:
        """Return the model the estimator runs, as JSON (coefficients as adapted so far)."""
        with self._lock:
            return self.model.to_dict()

    def stats(self) -> dict[str, Any]:
        """JSON statistics of the service (module docstring)."""
        with self._lock:
            published = self.published
            last = self.last_estimate
            return {
                "role": ROLE,
                "device": self.config.device,
                "model": {
                    "path": str(self.model_path) if self.model_path is not None else None,
                    "robot": self.model.robot,
                    "friction": self.model.friction.kind,
                },
                "uptime_s": round(time.perf_counter() - self._started_s, 3),
                "joint_states": {
                    **self.seqs.to_dict(),
                    "stream_restarts": self.stream_restarts,
                    "rate_hz": round(self.rate.rate_hz, 2),
                    "mean_rate_hz": round(self.rate.mean_rate_hz, 2),
                },
                "estimates": {
                    "published": published,
                    "singular": self.singular,
                    "errors": self.estimate_errors,
                    "last_error": self.last_error,
                },
                "malformed": {
                    "dropped": sum(self.malformed_by_key.values()),
                    "by_key": dict(self.malformed_by_key),
                    "last": self.last_malformed,
                },
                "latency_ms": self.latency.summary_ms(),
                "processing_ms": self.processing.summary_ms(),
                "on_ground_fraction": _fraction(self.on_ground_all, published),
                "on_ground_fraction_per_joint": [
                    _fraction(int(c), published) for c in self.on_ground_joint
                ],
                "adaptation": {
                    "enabled": self.adapting,
                    "available": not self.adaptation_note,
                    "note": self.adaptation_note,
                    "samples": 0 if self.adaptation is None else self.adaptation.samples,
                },
                "recording": None
                if self.writer is None
                else {"path": str(self.writer.path), "messages": self.writer.messages_written},
                "last_estimate": None
                if last is None
                else {
                    "source_seq": last.source_seq,
                    "f_n": [None if math.isnan(x) else x for x in last.f_n],
                },
            }


def _fraction(count: int, total: int) -> float | None:
    return None if total == 0 else round(count / total, 6)


def load_model(path: Path | None) -> tuple[DynamicModel, Path]:
    """Load ``path`` (default: the shipped model); raise ModelFileError."""
    model_path = Path(path) if path is not None else DEFAULT_MODEL_PATH
    return DynamicModel.load(model_path), model_path


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``python -m teleop_force.service``."""
    from teleop_force.zenoh_session import add_zenoh_arguments

    parser = argparse.ArgumentParser(
        prog="python -m teleop_force.service", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--device", default="slave", help="device to estimate on (default slave)")
    parser.add_argument("--master", default="master", help="master device id (recording metadata)")
    parser.add_argument(
        "--model", type=Path, default=None, help=f"model JSON (default {DEFAULT_MODEL_PATH.name})"
    )
    parser.add_argument("--record", type=Path, default=None, metavar="PATH", help="record to MCAP")
    parser.add_argument("--adapt", action="store_true", help="start with online WN adaptation on")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s")
    parser.add_argument(
        "--stats-json", default=None, metavar="PATH", help="final stats (- = stdout)"
    )
    add_zenoh_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the service until SIGINT / SIGTERM or ``--duration``; return the exit status."""
    args = build_parser().parse_args(argv)
    stop = StopSignal().install()
    use_realtime_switch_interval()
    try:
        if args.duration is not None and not args.duration > 0:
            raise ConfigurationError(f"--duration must be > 0, got {args.duration}")
        model, model_path = load_model(args.model)
        config = ServiceConfig(
            device=args.device, master=args.master, record_path=args.record, adapt=args.adapt
        )
        session = open_session(options_from_args(args))
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    try:
        service = ForceService(session, model, config, model_path=model_path)
        try:
            service.start()
            log(
                ROLE,
                f"estimating on {config.device} with {model_path.name} ({model.friction.kind})",
            )
            stop.wait(args.duration)
        finally:
            service.close()
        stats = service.stats()
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    finally:
        session.close()
    if args.stats_json:
        write_json(args.stats_json, stats)
    js = stats["joint_states"]
    log(
        ROLE,
        f"stopped: {js['received']} joint states, {js['lost']} lost, "
        f"{stats['malformed']['dropped']} malformed, {stats['estimates']['published']} estimates",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
