"""The slave-side force-estimation service: joint states in, force estimates out, over Zenoh.

For one device (``--device``, the slave)::

    subscribes  /<device>/measured_js         sensor_msgs/JointState: q, q̇, effort = motor torque
    publishes   /<device>/estimated_cf        geometry_msgs/WrenchStamped, one per joint state
    publishes   /<device>/estimate_diagnostics  teleop_force_msgs/EstimateDiagnostics (same stamp)
    publishes   /<device>/service/diagnostics   teleop_force_msgs/ServiceDiagnostics (1 Hz)
    queryable   omni/<device>/service/model   the model JSON (DynamicModel.to_dict());
                                              {"load": "/abs/model.json"}: run that model
    queryable   omni/<device>/service/control {"record": "start", "path": "/abs/x.mcap"},
                                              {"record": "stop"}
    queryable   omni/<device>/service/stats   JSON statistics (below)
    subscribes  omni/<device>/service/adapt   "on" / "off": online WN adaptation
    token       omni/<device>/alive/service

The ``/<device>/...`` topics are ROS 2 topics on rmw_zenoh's keys, with its attachment and
liveliness tokens: the service is the ROS 2 node ``teleop_force_service``
(:mod:`.ros2_edge`); the ``omni/<device>/...`` keys are the project's JSON controls.

The residual watch (:mod:`teleop_force.service.residual_watch`) tests, in a thread of its own
at 1 Hz, whether the external torque in free motion starts to depend on a variable; the
receive callback only appends the two payloads to its preallocated ring. The watch makes its
own external torque from the joint states, with the estimator it was calibrated on
(:mod:`~teleop_force.service.watch_residual`), whatever estimator the forces are published
with.

Each joint state is estimated on in the Zenoh receive thread that delivers it (the compiled
step of :class:`~teleop_force.estimation.estimator.ForceEstimator` costs microseconds: no
queue, no thread hop; the CDR JointState is decoded and the estimate encoded with
:mod:`teleop_force.ros2.codec`), streaming, with no
accelerations, with the time ``t = (t_ns - t0_ns) * 1e-9`` counted in integer nanoseconds
from the first sample of the stream, so the same stream gives the same floats whenever it is
played (a replay shifted in time included). A stream restarts, and the estimator with it,
when its ``seq`` (the attachment's sequence number) goes backwards or jumps far, or its
header stamp goes backwards or pauses > 0.5 s. The estimate's ``source_sequence`` is the
joint state's sequence number and its stamp the time it was published; the slave -> estimate
latency is measured from the joint state's attachment source time.

Statistics (``service/stats``): joint states received / lost (sequence gaps) / restarts /
duplicates, malformed messages dropped (by key; ``without_attachment``: joint states without
rmw_zenoh's attachment), estimates published, singular, errors,
latency p50/p99/max [ms] (joint-state stamp -> estimate publish), processing time, rates, the
fraction of estimates on trained ground, the model running (``model.path``), adaptation
state, recording (``recording``: the open one or ``null``; ``last_recording``), controls,
memory (``memory``: resident size and the trims of
:class:`~teleop_force.process.memory.MemoryTrimmer`). ``joint_states.backlog`` and
``overflow_dropped`` are kept for clients of older releases and stay 0: nothing is queued.
``zenoh_floor`` is ``null`` unless the process runs as the Zenoh floor (``--zenoh-floor``:
the same subscriptions and publication doing no work, for ``teleop-force bench``).

Bad input never stops the service: a malformed or wrong-version payload, a joint state with a
value beyond :data:`MAX_ABS_JOINT_VALUE` or of the wrong joint count is counted under
``malformed`` and dropped; an estimate that cannot be computed (non-finite result) is counted
under ``estimates.errors`` and the estimator restarts its stream at the next joint state, so
one bad sample cannot poison the filters for good.

Run-time controls (``service/model`` with a payload, ``service/control``; see
:mod:`teleop_force.service.controls` for the folder checks) are served by one thread of their
own, never on a Zenoh receive thread: a model is read and checked off the estimator's lock,
then swapped in between two samples (the new estimator starts a fresh stream); a recording
started at run time records what ``--record`` would, into a new file.

Recording (``--record PATH``, or the ``record`` control): every ROS 2 message of the domain
as received (:class:`~teleop_force.service.ros2_recorder.Ros2Recorder`, the session recorder's
own: a FIFO subscriber on ``<ROS_DOMAIN_ID>/**`` drained by a thread), the estimates this
service publishes included (a session hears its own publications), to an MCAP session of
profile ``ros2`` with metadata ``primary_device=<device>``, the model and the estimator.

Run: ``python -m teleop_force.service.force_service --device slave --connect tcp/127.0.0.1:7447``.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import queue
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import zenoh

from teleop_force.errors import (
    ConfigurationError,
    DataError,
    MessageError,
    ModelFileError,
    TeleopForceError,
)
from teleop_force.estimation.estimator import (
    TRAINED_GROUND_WEIGHT,
    ForceEstimator,
    estimator_from_args,
    estimator_metadata,
)
from teleop_force.estimation.flags import add_estimator_arguments
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.mcap_session import DEFAULT_FLUSH_INTERVAL_S, SessionWriter
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.process.lifetime import (
    StopSignal,
    log,
    use_realtime_switch_interval,
    write_json,
)
from teleop_force.process.memory import MemoryTrimmer
from teleop_force.robots.driver_interface import DriverInterface
from teleop_force.ros2 import codec, topics
from teleop_force.ros2 import graph as ros2_graph
from teleop_force.ros2.attachment import Attachment
from teleop_force.service.adaptation import (
    DEFAULT_FORCE_THRESHOLD_N,
    DEFAULT_GUARD_S,
    AdaptationGate,
)
from teleop_force.service.adaptation_state import AdaptationState
from teleop_force.service.controls import (
    ControlError,
    create_exclusively,
    model_folders,
    parse_request,
    read_model_file,
    record_folders,
)
from teleop_force.service.counters import (
    MAX_COUNTED_KEYS,
    ControlCounters,
    EstimateCounters,
    JointStateCounters,
    MalformedCounter,
)
from teleop_force.service.recording_state import RecordingState
from teleop_force.service.residual_watch import ResidualWatch
from teleop_force.service.ros2_edge import Ros2Edge
from teleop_force.service.ros2_recorder import PROFILE as RECORDING_PROFILE
from teleop_force.service.ros2_recorder import Ros2Recorder, recorded_key
from teleop_force.service.stream_clock import StreamClock
from teleop_force.service.watch_residual import WatchResidual
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import (
    declare_json_queryable,
    declare_queryable,
    declare_subscriber,
    declare_token,
    reply_json,
    undeclare_all,
)
from teleop_force.transport.session import open_session, options_from_args

ROLE: Final = "service"
SEQ_MASK: Final = 0xFFFF_FFFF
#: The control thread is waited for at most this long on close [s].
DRAIN_TIMEOUT_S: Final = 10.0
#: A joint-state value (rad, rad/s, N m) beyond this is implausible: counted as malformed.
MAX_ABS_JOINT_VALUE: Final = 1e6
#: ROS 2's largest domain id (``ROS_DOMAIN_ID``: 0..232 on Linux, as DDS maps it to ports).
MAX_DOMAIN_ID: Final = 232
#: Without a joint state for this long, the service says so on stderr [s].
INPUT_SILENCE_S: Final = 1.0


@dataclass(frozen=True)
class ServiceConfig:
    """Settings of :class:`ForceService`.

    Attributes:
        device: Device whose joint states are estimated on.
        master: Device id of the master (recorded in the metadata only).
        record_path: MCAP session to record to (``None``: no recording).
        adapt: Start with online adaptation on (needs a WN friction).
        source: ``live`` or ``replay`` (recorded in the metadata).
        models_dirs: Folders models may be loaded from on request, besides ``recordings/``
            and ``teleop_force/models/``.
        record_dirs: Folders recordings may be started in on request, besides ``recordings/``.
        record_flush_s: A recording's chunk is handed to the OS at least this often [s].
        zenoh_floor: Measure the Zenoh floor: the same subscriptions (the joint states, and
            the recorded keys when ``record_path`` is set) and the same publication (one
            estimate-sized payload per joint state), doing no work: no decoding, no estimate,
            no recording. ``teleop-force bench`` compares the service's CPU with it.
        residual_watch: Run the residual watch and publish its diagnostics.
        adapt_gate: Which samples online adaptation learns from (free motion only).
        domain_id: The ROS domain of its topics (``None``: ``ROS_DOMAIN_ID``, default 0).
        driver: The device's JointStates are a driver's, in its conventions, converted with
            this interface on reading (``None``: they are in the model's coordinates).

    """

    device: str = "slave"
    master: str | None = "master"
    record_path: Path | None = None
    adapt: bool = False
    source: str = "live"
    models_dirs: tuple[Path, ...] = ()
    record_dirs: tuple[Path, ...] = ()
    record_flush_s: float = DEFAULT_FLUSH_INTERVAL_S
    zenoh_floor: bool = False
    residual_watch: bool = True
    adapt_gate: AdaptationGate = field(default_factory=AdaptationGate)
    domain_id: int | None = None
    driver: DriverInterface | None = None

    def __post_init__(self) -> None:
        """Validate the device ids and the recording settings."""
        keys.validate_chunk(self.device)
        topics.validate_device(self.device)
        if self.master is not None:
            keys.validate_chunk(self.master, "master device id")
        if self.record_path is not None:
            object.__setattr__(self, "record_path", Path(self.record_path))
        if self.source not in ("live", "replay"):
            raise ConfigurationError(f"source must be live or replay, got {self.source!r}")
        object.__setattr__(self, "models_dirs", tuple(Path(d) for d in self.models_dirs))
        object.__setattr__(self, "record_dirs", tuple(Path(d) for d in self.record_dirs))
        if not (math.isfinite(self.record_flush_s) and self.record_flush_s > 0.0):
            raise ConfigurationError(f"record_flush_s must be > 0, got {self.record_flush_s}")
        if self.domain_id is not None and not 0 <= self.domain_id <= MAX_DOMAIN_ID:
            raise ConfigurationError(
                f"ROS domain id must be 0..{MAX_DOMAIN_ID}, got {self.domain_id}"
            )


class ForceService:
    """Streaming force estimation of one device on a Zenoh session (module docstring)."""

    def __init__(
        self,
        session: zenoh.Session,
        model: DynamicModel,
        config: ServiceConfig | None = None,
        *,
        model_path: Path | None = None,
        memory: MemoryTrimmer | None = None,
    ) -> None:
        """Prepare the estimator (and the recording file); call :meth:`start` to go live.

        ``memory``: the process's trimmer (started and stopped by its owner, the service
        process), reported under ``memory`` in the statistics.

        The state is kept in named parts, each read by :meth:`stats`: :attr:`stream` (the
        stream clock and its restart rule), :attr:`joint_states` and :attr:`estimates` (the
        counters and histograms), :attr:`malformed`, :attr:`controls` (run-time requests),
        :attr:`adaptation_state` and :attr:`recording`. The model running (:attr:`model`,
        :attr:`model_path`, :attr:`estimator`) is swapped by :meth:`load_model_file`.
        """
        self.session = session
        self.config = config if config is not None else ServiceConfig()
        self.memory = memory
        self.model, self.model_path = model, model_path
        self.estimator = ForceEstimator(model)
        self.estimator.warm_up()
        self.n_joints = model.n_joints
        self.allowed_models = model_folders(self.config.models_dirs)
        self.allowed_records = record_folders(self.config.record_dirs)
        self._own_js_key = keys.measured_js(self.config.device)
        self._own_js_topic = topics.topic_name(self.config.device, topics.MEASURED_JS)
        self._estimate_key = keys.estimated_cf(self.config.device)
        self._init_runtime()
        self.stream = StreamClock()
        self.joint_states = JointStateCounters()
        self.estimates = EstimateCounters(self.n_joints)
        self.malformed = MalformedCounter()
        self.controls = ControlCounters()
        self.adaptation_state = AdaptationState(self.estimator, self.config.adapt_gate)
        self.recording = RecordingState()
        self.residual_watch = (
            ResidualWatch(
                self.n_joints,
                device=self.config.device,
                model_path=None if model_path is None else str(model_path),
                recording_path=self._recording_path,
                residual=WatchResidual(self.model).warm_up(),
            )
            if self.config.residual_watch and not self.config.zenoh_floor
            else None
        )
        if self.config.adapt:
            self.set_adaptation(True)
        zeros = [0.0] * self.n_joints
        self._floor_payloads = codec.encode_estimate_parts(
            0, 0, (0.0, 0.0, 0.0), zeros, zeros, [False] * self.n_joints, zeros, zeros,
            topics.model_joint_names(self.n_joints), topics.BASE_FRAME,
        )  # fmt: skip
        self._floor_received = 0
        if self.config.record_path is not None and not self.config.zenoh_floor:
            self.recording.recorder = Ros2Recorder(
                session, self._open_writer(self.config.record_path), self._count_malformed,
                domain_id=self.config.domain_id,
            )  # fmt: skip

    def _init_runtime(self) -> None:
        """Prepare the lock, queues, threads, Zenoh entity slots and the run-time bookkeeping."""
        self._lock = threading.Lock()
        self._closed = False
        self._entities: list[Any] = []
        self._ros2: Ros2Edge | None = None
        self._queries: queue.SimpleQueue[tuple[str, zenoh.Query] | None] = queue.SimpleQueue()
        self._control_thread: threading.Thread | None = None
        self._logged: set[str] = set()
        self._started_s = time.perf_counter()

    # -- lifetime -----------------------------------------------------------------------------

    def _open_writer(self, path: Path) -> SessionWriter:
        path.parent.mkdir(parents=True, exist_ok=True)
        metadata = {
            "primary_device": self.config.device,
            "source": self.config.source,
            "robot": self.model.robot,
            "friction": self.model.friction.kind,
            "model": str(self.model_path) if self.model_path is not None else "",
            "recorder": "teleop_force.service.force_service",
            **estimator_metadata(self.model),  # a replay runs the same estimator
        }
        if self.config.master is not None:
            metadata["master_device"] = self.config.master
        return SessionWriter(
            path, metadata, flush_interval_s=self.config.record_flush_s, profile=RECORDING_PROFILE
        )

    def start(self) -> ForceService:
        """Declare the publisher, subscribers, queryables and token; return self."""
        device = self.config.device
        session = self.session
        edge = self._ros2 = Ros2Edge(
            session, device, self.n_joints, self._estimate_guarded, self._count_malformed,
            self.config.domain_id, self.config.driver,
        )  # fmt: skip
        watch = self.residual_watch
        if watch is not None:
            watch.start(edge.publish_service_diagnostics)
        self._control_thread = threading.Thread(
            target=self._serve_controls, name="controls", daemon=True
        )
        self._control_thread.start()
        if self.config.zenoh_floor:
            edge.subscribe(self._on_own_js_floor)
            if self.config.record_path is not None:
                self._subscribe_recorded(self._on_recorded_floor)
        else:
            edge.subscribe()
            if self.recording.recorder is not None:
                self.recording.recorder.start()
        self._entities.append(
            declare_subscriber(session, keys.service_adapt(device), self._on_adapt)
        )
        for kind, key in (
            ("model", keys.service_model(device)),
            ("control", keys.service_control(device)),
        ):
            self._entities.append(declare_queryable(session, key, self._control_callback(kind)))
        self._entities.append(
            declare_json_queryable(session, keys.service_stats(device), self.stats)
        )
        self._entities.append(declare_token(session, keys.alive(device, ROLE)))
        self._started_s = time.perf_counter()
        return self

    def close(self) -> None:
        """Stop processing, undeclare everything, then close the recording (idempotent).

        The inputs go first; the ROS 2 node (its subscription and publishers) is undeclared
        under the estimator's lock, so no receive thread is publishing then (a callback that
        comes after sees the service closed). The recorder writes what was queued before it
        closes the file.
        """
        with self._lock:
            already = self._closed
            self._closed = True
        if self.residual_watch is not None:
            self.residual_watch.stop()  # before its publisher goes
        entities, self._entities = self._entities, []
        recorded = self.recording.take_entities()
        undeclare_all(*reversed(entities), *recorded)
        with self._lock:
            edge, self._ros2 = self._ros2, None
            if edge is not None:
                edge.close()
        if already:
            return
        if self._control_thread is not None:
            self._queries.put(None)
            self._control_thread.join(DRAIN_TIMEOUT_S)
        with self._lock:
            self.adaptation_state.close()  # the adaptation worker's thread
        recorder = self.recording.recorder
        if recorder is not None:
            recorder.close()
            self.recording.last = recorder.stats()

    def __enter__(self) -> ForceService:
        """Start the service."""
        return self.start()

    def __exit__(self, *exc: object) -> None:
        """Close the service."""
        self.close()

    # -- callbacks ----------------------------------------------------------------------------

    def _estimate_guarded(self, msg: m.JointState, attachment: Attachment, arrival_ns: int) -> None:
        """Estimate on one JointState of the device, in the receive thread, and publish.

        One step costs microseconds (the compiled estimator), so it runs here: no queue, no
        thread hop. Nothing may escape a receive thread: an unexpected error is counted (and
        logged once per kind) and the next joint state is estimated on.
        """
        if self._closed:
            return
        try:
            self._on_joint_state(msg, attachment)
        except Exception as exc:  # nothing may stop the estimation
            # TeleopForceError: e.g. the session went away under us; anything else is a bug,
            # logged once per kind, and the next joint state is estimated on regardless.
            with self._lock:
                self.estimates.count_error(f"{type(exc).__name__}: {exc}")
                self.stream.reset()
            if not isinstance(exc, TeleopForceError):
                self._log_once(f"estimator: unexpected {type(exc).__name__}: {exc}")

    def _subscribe_recorded(self, callback: Any) -> None:
        """Zenoh floor: the recorded key expression, every sample handed to ``callback``."""
        key = recorded_key(self.domain_id)
        self.recording.entities.append(declare_subscriber(self.session, key, callback, direct=True))

    def _on_own_js_floor(self, payload: bytes, attachment: Attachment) -> None:
        """Zenoh floor (``zenoh_floor``): publish a fixed estimate-sized pair, nothing else."""
        edge = self._ros2
        if edge is not None and not self._closed:
            edge.publish_payloads(*self._floor_payloads)
            self._floor_received += 1

    def _on_recorded_floor(self, sample: zenoh.Sample) -> None:
        """Zenoh floor: a recorded key's sample, received and dropped."""

    def _count_malformed(self, key: str, exc: Exception) -> None:
        with self._lock:
            self.malformed.count(key, exc)

    def _on_joint_state(self, msg: m.JointState, attachment: Attachment) -> None:
        """Check one joint state, estimate on it, publish, hand both to the residual watch."""
        seq = msg.seq
        try:
            n = len(msg.q_rad)
            if n != self.n_joints:
                raise MessageError(f"{n} joints, the model has {self.n_joints}")
            values = (*msg.q_rad, *msg.qd_rad_s, *msg.effort_nm)
            limit = MAX_ABS_JOINT_VALUE
            if not all(-limit <= x <= limit for x in values):
                raise MessageError(f"a value is beyond +-{limit:g} (seq {seq})")
        except MessageError as exc:
            self._count_malformed(self._own_js_topic, exc)
            return
        watch = self.residual_watch
        with self._lock:
            estimate = self._estimate_locked(msg, attachment, values)
            if estimate is not None and watch is not None:
                # the watch's ring keeps fixed-layout records, decoded in bulk by its thread
                joint_state = m.pack_joint_state(seq, msg.t_ns, *(values[k * n : (k + 1) * n]
                                                                  for k in range(3)))  # fmt: skip
                watch.append(joint_state, estimate)  # two stores into its ring, nothing else

    def _estimate_locked(
        self, msg: m.JointState, attachment: Attachment, values: tuple[float, ...]
    ) -> bytes | None:
        """Estimate on one joint state and publish; return the watch's record of it."""
        started_s = time.perf_counter()
        edge = self._ros2
        if self._closed or edge is None:
            return None
        seq, t_ns = msg.seq, msg.t_ns
        event = self.joint_states.seqs.observe(seq)
        if event.duplicate:
            return None
        self.joint_states.rate.tick()
        stream, estimator, adapt = self.stream, self.estimator, self.adaptation_state
        online = adapt.adaptation
        if stream.advance(t_ns, event.restarted):
            estimator.reset()
            if online is not None:
                online.reset()
        t_s = stream.t_s
        n = self.n_joints
        q = values[:n]
        tau = values[2 * n :]
        counters = self.estimates
        try:
            out = estimator.step(t_s, q, tau).tolist()
            if adapt.enabled and online is not None:
                online.submit(t_s, q, tau, out)  # a deque append; adapted by its worker
        except (DataError, ArithmeticError) as exc:
            counters.count_error(str(exc))
            stream.reset()
            return None
        # out: [F (3), tau_ext, tau_motor_L, tau_model_L, weight (n each), singular]
        force = out[:3]
        joint_space = out[3 : 3 + 4 * n]
        if not math.isfinite(sum(joint_space)) or math.inf in force or -math.inf in force:
            # A non-finite result: the filter states may hold inf / NaN now, so the next joint
            # state starts a fresh stream instead of failing forever.
            counters.count_error(f"non-finite estimate at seq {seq}")
            stream.reset()
            return None
        weight = out[3 + 3 * n : 3 + 4 * n]
        trained = [w >= TRAINED_GROUND_WEIGHT for w in weight]
        published_ns = time.time_ns()
        tau_ext, motor, model = out[3 : 3 + n], out[3 + n : 3 + 2 * n], out[3 + 2 * n : 3 + 3 * n]
        edge.publish_estimate(
            published_ns, attachment.sequence_number, force, tau_ext, weight, trained, motor,
            model,
        )  # fmt: skip
        mask = sum(1 << j for j in range(n) if trained[j])
        estimate_seq = counters.published & SEQ_MASK
        counters.count_published(
            seq, force, mask, n, out[3 + 4 * n] != 0.0, attachment.source_timestamp_ns, started_s
        )
        if self.residual_watch is None:
            return None
        return m.pack_force_estimate(
            estimate_seq, published_ns, seq, n,
            [*force, *tau_ext, *weight, *motor, *model], mask,
        )  # fmt: skip

    @property
    def domain_id(self) -> int:
        """The ROS domain the service's node is on."""
        edge = self._ros2
        if edge is not None:
            return edge.node.domain_id
        if self.config.domain_id is not None:
            return self.config.domain_id
        return ros2_graph.domain_id_from_env()

    def _recording_path(self) -> str | None:
        """Return the file the service records to, if it does (for the watch's command)."""
        recorder = self.recording.recorder
        return None if recorder is None else str(recorder.writer.path)

    def _log_once(self, message: str) -> None:
        if message not in self._logged and len(self._logged) < MAX_COUNTED_KEYS:
            self._logged.add(message)
            log(ROLE, message)

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

    # -- run-time controls (own thread) -------------------------------------------------------

    def _control_callback(self, kind: str) -> Any:
        def on_query(query: zenoh.Query) -> None:
            if self._closed:
                query.drop()
                return
            self._queries.put((kind, query))

        return on_query

    def _serve_controls(self) -> None:
        """Control thread: answer model / control queries one at a time, in arrival order."""
        while True:
            item = self._queries.get()
            if item is None:
                return
            kind, query = item
            key = (
                keys.service_model(self.config.device)
                if kind == "model"
                else keys.service_control(self.config.device)
            )
            try:
                reply_json(query, key, self._answer(kind, key, query))
            finally:
                query.drop()

    def _answer(self, kind: str, key: str, query: zenoh.Query) -> Any:
        """Return the reply to one control query (a refusal: ``{"ok": false, "error": ...}``)."""
        payload = query.payload
        try:
            request = parse_request(None if payload is None else payload.to_bytes())
        except ControlError as exc:
            self._count_malformed(key, exc)
            return self._refuse(str(exc))
        if kind == "model" and request is None:
            return self.model_dict()
        with self._lock:
            self.controls.requests += 1
        try:
            if kind == "model":
                return self._model_request(request or {})
            return self._control_request(request or {})
        except (ControlError, TeleopForceError, OSError) as exc:
            return self._refuse(str(exc))
        except Exception as exc:  # a bad request must not stop the control thread
            self._log_once(f"control: unexpected {type(exc).__name__}: {exc}")
            return self._refuse(f"internal error: {type(exc).__name__}: {exc}")

    def _refuse(self, error: str) -> dict[str, Any]:
        with self._lock:
            self.controls.count_refusal(error)
        log(ROLE, f"control request refused: {error}")
        return {"ok": False, "error": error}

    def _model_request(self, request: dict[str, Any]) -> dict[str, Any]:
        if set(request) != {"load"}:
            raise ControlError(f'expected {{"load": PATH}}, got keys {sorted(request)}')
        path = self.load_model_file(request["load"])
        return {"ok": True, "path": str(path), "friction": self.model.friction.kind}

    def _control_request(self, request: dict[str, Any]) -> dict[str, Any]:
        action = request.get("record")
        if action == "start" and set(request) == {"record", "path"}:
            path = self.start_recording(request["path"])
            return {"ok": True, "path": str(path)}
        if action == "stop" and set(request) == {"record"}:
            final = self.stop_recording()
            return {"ok": True, **final}
        raise ControlError(
            'expected {"record": "start", "path": PATH} or {"record": "stop"}, '
            f"got {_json_preview(request)}"
        )

    def load_model_file(self, path_text: object) -> Path:
        """Load a model from an allowed folder and run it from the next sample on.

        The file is read, its estimator built and tried on a few samples outside the lock;
        only the swap itself holds it. Raises ControlError (or a TeleopForceError of the file).
        """
        path = self.allowed_models.model_file(path_text)
        try:
            model = read_model_file(path)
            if model.n_joints != self.n_joints:
                raise ControlError(
                    f"{path}: model has {model.n_joints} joints, the device has {self.n_joints}"
                )
            estimator = ForceEstimator(model)
            _try_estimator(ForceEstimator(model), path)
        except TeleopForceError:
            raise
        except _INCONSISTENT_MODEL_ERRORS as exc:
            raise ControlError(f"{path}: inconsistent model: {type(exc).__name__}: {exc}") from None
        with self._lock:
            self.model, self.estimator, self.model_path = model, estimator, path
            self.adaptation_state.follow(estimator)
            self.stream.reset()
            self.controls.loads += 1
        if self.residual_watch is not None:
            # a new baseline for the new model, tested with the watch's estimator of it
            self.residual_watch.reset(model_path=str(path), residual=WatchResidual(model).warm_up())
        log(ROLE, f"now estimating with {path} ({model.friction.kind})")
        return path

    def start_recording(self, path_text: object) -> Path:
        """Start recording into a new file of an allowed folder; raise ControlError."""
        current = self.recording.recorder
        if current is not None:
            raise ControlError(f"already recording to {current.writer.path}; stop it first")
        path = self.allowed_records.new_recording(path_text)
        create_exclusively(path)
        try:
            writer = self._open_writer(path)
        except TeleopForceError:
            _remove_quietly(path)
            raise
        recorder = Ros2Recorder(
            self.session, writer, self._count_malformed, domain_id=self.config.domain_id
        )
        try:
            recorder.start()
        except TeleopForceError:
            recorder.close()
            _remove_quietly(path)
            raise
        with self._lock:
            self.recording.recorder = recorder
        log(ROLE, f"recording to {path}")
        return path

    def stop_recording(self) -> dict[str, Any]:
        """Stop the recording and close its file; return its final counters."""
        recorder = self.recording.recorder
        if recorder is None:
            raise ControlError("not recording")
        with self._lock:
            self.recording.recorder = None
        recorder.close()
        final = recorder.stats()
        self.recording.last = final
        log(ROLE, f"recording stopped: {final['path']} ({final['messages']} messages)")
        return final

    # -- control and reporting ----------------------------------------------------------------

    def set_adaptation(self, on: bool) -> None:
        """Switch online adaptation on or off; raise ConfigurationError if impossible."""
        with self._lock:
            self.adaptation_state.switch(on, self.estimator)

    def model_dict(self) -> dict[str, Any]:
        """Return the model the estimator runs, as JSON (coefficients as adapted so far)."""
        with self._lock:
            return self.model.to_dict()

    def stats(self) -> dict[str, Any]:
        """JSON statistics of the service (module docstring)."""
        with self._lock:
            estimates = self.estimates
            return {
                "role": ROLE,
                "device": self.config.device,
                "model": {
                    "path": str(self.model_path) if self.model_path is not None else None,
                    "robot": self.model.robot,
                    "friction": self.model.friction.kind,
                    "loads": self.controls.loads,
                },
                "uptime_s": round(time.perf_counter() - self._started_s, 3),
                "joint_states": self.joint_states.to_dict(
                    stream_restarts=self.stream.restarts, backlog=0
                ),
                "estimates": estimates.to_dict(),
                "zenoh_floor": (
                    {"joint_states_received": self._floor_received}
                    if self.config.zenoh_floor
                    else None
                ),
                "malformed": {
                    **self.malformed.to_dict(),
                    "without_attachment": (
                        0 if self._ros2 is None else self._ros2.malformed_attachments
                    ),
                },
                "latency_ms": estimates.latency.summary_ms(),
                "processing_ms": estimates.processing.summary_ms(),
                "on_ground_fraction": estimates.on_ground_fraction(),
                "on_ground_fraction_per_joint": estimates.on_ground_fraction_per_joint(),
                "adaptation": self.adaptation_state.to_dict(),
                "recording": self.recording.current_stats(),
                "last_recording": self.recording.last,
                "memory": None if self.memory is None else self.memory.stats(),
                "controls": self.controls.to_dict(),
                "last_estimate": estimates.last_estimate_dict(),
                "residual_watch": (
                    None if self.residual_watch is None else self.residual_watch.stats()
                ),
            }


def _try_estimator(estimator: ForceEstimator, path: Path) -> None:
    """Run a fresh estimator on a few samples at rest; raise ModelFileError if it misbehaves.

    The samples are tuples of floats, as the service's: the kernels it compiles or loads are
    the ones the stream runs.
    """
    description = estimator.model.description()
    lo = np.asarray(description.q_min_rad, dtype=float)
    hi = np.asarray(description.q_max_rad, dtype=float)
    n = estimator.n
    q = 0.5 * (lo + hi) if lo.shape == (n,) and hi.shape == (n,) else np.zeros(n)
    q_rad, tau_nm = tuple(float(x) for x in q), (0.0,) * n
    for k in range(3):
        out = estimator.step(k * 1e-3, q_rad, tau_nm)
    if not np.all(np.isfinite(out[3 : 3 + 3 * n])):  # tau_ext and the filtered torques
        raise ModelFileError("the model gives non-finite torques at rest", path=path)
    estimator.reset()


def _json_preview(value: Any, limit: int = 120) -> str:
    """Return a short one-line JSON rendering of ``value`` for messages."""
    text = json.dumps(value, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _remove_quietly(path: Path) -> None:
    """Remove ``path`` if it exists, ignoring errors (clean-up after a failed start)."""
    try:
        os.unlink(path)
    except OSError:
        return


#: What a model file the loader accepted may still raise when its estimator is built or run
#: (fuzzing found each of these; see docs/reliability.md): reported as a bad model file.
_INCONSISTENT_MODEL_ERRORS: Final = (ArithmeticError, LookupError, NameError, TypeError, ValueError)


def load_model(path: Path | None) -> tuple[DynamicModel, Path]:
    """Load ``path`` (default: the shipped model) and try it; raise ModelFileError."""
    model_path = Path(path) if path is not None else DEFAULT_MODEL_PATH
    try:
        model = DynamicModel.load(model_path)
        _try_estimator(ForceEstimator(model), model_path)
    except TeleopForceError:
        raise
    except _INCONSISTENT_MODEL_ERRORS as exc:
        raise ModelFileError(
            f"inconsistent model: {type(exc).__name__}: {exc}", path=model_path
        ) from None
    return model, model_path


def build_parser(
    prog: str = "python -m teleop_force.service.force_service",
) -> argparse.ArgumentParser:
    """Return the argument parser of the service (``teleop-force serve``)."""
    from teleop_force.transport.session import add_zenoh_arguments

    parser = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="slave", help="device to estimate on (default slave)")
    parser.add_argument("--master", default="master", help="master device id (recording metadata)")
    parser.add_argument(
        "--model", type=Path, default=None, help=f"model JSON (default {DEFAULT_MODEL_PATH.name})"
    )
    parser.add_argument("--record", type=Path, default=None, metavar="PATH", help="record to MCAP")
    parser.add_argument(
        "--models-dir", type=Path, action="append", default=[], metavar="DIR",
        help="extra folder models may be loaded from at run time (repeatable)",
    )  # fmt: skip
    parser.add_argument(
        "--record-dir", type=Path, action="append", default=[], metavar="DIR",
        help="extra folder recordings may be started in at run time (repeatable)",
    )  # fmt: skip
    parser.add_argument(
        "--record-flush-s", type=float, default=DEFAULT_FLUSH_INTERVAL_S, metavar="S",
        help="hand recorded chunks to the OS at least every S s "
        f"(default {DEFAULT_FLUSH_INTERVAL_S:g})",
    )  # fmt: skip
    parser.add_argument("--adapt", action="store_true", help="start with online WN adaptation on")
    parser.add_argument(
        "--adapt-free-force-n", type=float, default=DEFAULT_FORCE_THRESHOLD_N, metavar="N",
        help="adapt only while the estimated tip force is below N newtons "
        f"(default {DEFAULT_FORCE_THRESHOLD_N:g})",
    )  # fmt: skip
    parser.add_argument(
        "--adapt-guard-s", type=float, default=DEFAULT_GUARD_S, metavar="S",
        help=f"and not within S s of a contact (default {DEFAULT_GUARD_S:g})",
    )  # fmt: skip
    add_estimator_arguments(parser)
    parser.add_argument(
        "--zenoh-floor", action="store_true",
        help="measure the Zenoh floor: same subscriptions and publication, no work (bench)",
    )  # fmt: skip
    parser.add_argument(
        "--no-residual-watch", action="store_true",
        help="do not run the residual watch (/<device>/service/diagnostics)",
    )  # fmt: skip
    parser.add_argument(
        "--driver", default=None, metavar="NAME|FILE",
        help="the device's JointStates are this driver's, converted on reading: a built-in "
        "(sensable-phantom: sawSensablePhantom's Omni / Touch) or a driver description file",
    )  # fmt: skip
    parser.add_argument(
        "--ros-domain-id", type=int, default=None, metavar="D",
        help="ROS 2 domain of the device's topics (default: $ROS_DOMAIN_ID, else 0)",
    )  # fmt: skip
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s")
    parser.add_argument(
        "--stats-json", default=None, metavar="PATH", help="final stats (- = stdout)"
    )
    add_zenoh_arguments(parser)
    return parser


def wait_reporting_silence(
    service: ForceService, stop: StopSignal, duration_s: float | None, endpoint: str
) -> None:
    """Wait for ``stop`` or ``duration_s``; say on stderr when no joint state came for 1 s.

    One line when the input falls silent (or never started), one when it comes back.
    """
    deadline = None if duration_s is None else time.monotonic() + duration_s
    topic = topics.topic_name(service.config.device, topics.MEASURED_JS)
    seen, seen_at, silent = service.joint_states.rate.total, time.monotonic(), False
    while True:
        step = INPUT_SILENCE_S / 4
        if deadline is not None:
            step = min(step, deadline - time.monotonic())
            if step <= 0.0:
                return
        if stop.wait(step):
            return
        now, count = time.monotonic(), service.joint_states.rate.total
        if count != seen:
            if silent:
                log(ROLE, f"joint states on {topic} again")
            seen, seen_at, silent = count, now, False
        elif not silent and now - seen_at >= INPUT_SILENCE_S:
            silent = True
            what = "no joint state yet" if count == 0 else "no joint state"
            log(
                ROLE,
                f"{what} on {topic} for {now - seen_at:.1f} s (is the driver publishing, on "
                f"ROS domain {service.domain_id}, through {endpoint}?)",
            )


def main(argv: Sequence[str] | None = None, prog: str | None = None) -> int:
    """Run the service until SIGINT / SIGTERM or ``--duration``; return the exit status."""
    args = (build_parser() if prog is None else build_parser(prog)).parse_args(argv)
    stop = StopSignal().install().watch_supervisor()
    use_realtime_switch_interval()
    try:
        if args.duration is not None and not args.duration > 0:
            raise ConfigurationError(f"--duration must be > 0, got {args.duration}")
        model, model_path = load_model(args.model)
        model = estimator_from_args(model, args)
        config = ServiceConfig(
            device=args.device,
            master=args.master,
            record_path=args.record,
            adapt=args.adapt,
            models_dirs=tuple(args.models_dir),
            record_dirs=tuple(args.record_dir),
            record_flush_s=args.record_flush_s,
            zenoh_floor=args.zenoh_floor,
            residual_watch=not args.no_residual_watch,
            adapt_gate=AdaptationGate(args.adapt_free_force_n, args.adapt_guard_s),
            domain_id=args.ros_domain_id,
            driver=None if args.driver is None else load_driver(args.driver),
        )
        session = open_session(options_from_args(args))
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    trimmer = MemoryTrimmer().start()  # a long-running process: RSS follows what is live
    try:
        service = ForceService(session, model, config, model_path=model_path, memory=trimmer)
        try:
            service.start()
            # a long-running 1 kHz process: what start-up made is never garbage, so the
            # collector's full passes (tens of ms, stalls of the receive path) skip it
            gc.collect()
            gc.freeze()
            log(
                ROLE,
                f"estimating on {config.device} with {model_path.name} ({model.friction.kind})",
            )
            wait_reporting_silence(service, stop, args.duration, _endpoints(args))
        finally:
            service.close()
        stats = service.stats()
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    finally:
        trimmer.stop()
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


def load_driver(name_or_path: str) -> DriverInterface:
    """Return a built-in driver interface by name, else the one a description file holds."""
    from teleop_force.robots.registry import resolve_driver

    return resolve_driver(name_or_path)


def _endpoints(args: argparse.Namespace) -> str:
    connect = list(getattr(args, "connect", None) or [])
    return ", ".join(connect) if connect else "this machine's Zenoh peers"


if __name__ == "__main__":
    sys.exit(main())
