"""Re-estimation of a recording: what the force service would have published, computed offline.

``teleop-force replay REC --with-service --record OUT`` (the use "run today's model over last
week's session") needs no Zenoh and no real time: the recording's joint states are put through
the service's own rules and the batch form of its estimator, and a new recording is written
with what the service would have recorded.

The rules are the service's (:class:`~teleop_force.service.force_service.ForceService`), in
the order it received the joint states (the recording's log-time order):

* a joint state with a value beyond :data:`~teleop_force.service.force_service.
  MAX_ABS_JOINT_VALUE` is malformed: dropped and counted (a joint count other than the
  model's is refused here, as bad input);
* its ``seq`` goes through the service's
  :class:`~teleop_force.transport.stream_stats.SequenceTracker` (duplicates get no estimate)
  and its stamp through the service's :class:`~teleop_force.service.stream_clock.StreamClock`:
  a new stream, and a fresh estimator, where the service would begin one; time is counted in
  integer nanoseconds from each stream's first stamp;
* the estimates are :class:`~teleop_force.estimation.batch.BatchEstimator`'s (the streaming
  estimator's numbers, to rounding); one that is not finite is counted as an error and the
  next joint state starts a new stream, as the service does.

The new recording is a ROS 2 session (MCAP profile ``ros2``), as the service records one: every
recorded joint state (of every device), setpoint, true contact force and status on its ROS 2
topic with its recorded log time (a session recorded from ROS 2: the bytes, sequence and
publish time as recorded, copied chunk by chunk; an older one: encoded as a replay publishes
it), and per estimate a ``/<device>/estimated_cf`` WrenchStamped and a
``/<device>/estimate_diagnostics`` with one header stamp: their MCAP sequence counts the
estimates published (from 1, as the service's publishers do), ``source_sequence`` is the joint
state's sequence number, exactly as live. What differs from a live run: nothing is published
over Zenoh, the messages keep their recorded stamps (a replay over Zenoh shifts them to the
present), and an estimate's stamp (its publish time, which no offline computation has) is its
joint state's recorded log time, the time the recording service received it, so latencies read
off the new recording are the slave-to-service transport alone. The model is fixed: no online
adaptation.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from teleop_force.errors import ConfigurationError, DataError, MessageError
from teleop_force.estimation.batch import BatchEstimates, BatchEstimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.cdr_columns import JointStateArrays
from teleop_force.io.mcap_session import (
    MEASURED_JS,
    RawMessage,
    SessionReader,
    SessionWriter,
    read_joint_state_arrays,
)
from teleop_force.io.replay import (
    check_one_kind,
    primary_device,
    replayed_topics,
    ros2_payload,
    ros2_topic,
)
from teleop_force.io.ros2_columns import EstimateRows, estimate_blocks
from teleop_force.ros2 import topics as ros_topics
from teleop_force.service.counters import JointStateCounters, MalformedCounter
from teleop_force.service.force_service import MAX_ABS_JOINT_VALUE
from teleop_force.service.stream_clock import StreamClock
from teleop_force.transport import messages as m

#: More estimates than this that are not finite: the model is unusable, re-estimation stops.
MAX_ERRORS: Final = 100
#: Messages handed to the writer at once.
_WRITE_BATCH: Final = 100_000


@dataclass(frozen=True)
class Reestimation:
    """What :func:`reestimate_session` read, computed and wrote.

    Attributes:
        device: The primary device (whose joint states were estimated on).
        source: The recording read.
        target: The recording written.
        replayed: Messages per key taken from the source (what a replay would publish).
        written: Messages written to the target, estimates included.
        recorded_span_s: Log-time span of those messages in the source [s].
        duration_s: Wall time of the whole re-estimation [s].
        service: The statistics the service would report (``service/stats`` keys).

    """

    device: str
    source: Path
    target: Path
    replayed: dict[str, int]
    written: int
    recorded_span_s: float
    duration_s: float
    service: dict[str, Any]

    def __post_init__(self) -> None:
        """Check the counts and durations."""
        if self.written < 0 or any(count < 0 for count in self.replayed.values()):
            raise DataError("message counts must be >= 0")
        if self.recorded_span_s < 0.0 or self.duration_s < 0.0:
            raise DataError("durations must be >= 0")


@dataclass(frozen=True)
class _ServiceRun:
    """The service's decisions on the primary joint states, and its estimates."""

    estimated: np.ndarray  # indices (into the joint states) of the estimated ones
    source_seq: np.ndarray  # their seq
    published: np.ndarray  # mask over ``estimated``: an estimate was published
    estimates: BatchEstimates  # rows for ``estimated`` (unpublished rows: errors)
    plausible: np.ndarray  # mask over the joint states: estimated on (not malformed)
    joint_states: JointStateCounters
    malformed: MalformedCounter
    stream_restarts: int
    errors: int
    last_error: str


def reestimate_session(
    source: str | Path | SessionReader,
    target: str | Path,
    model: DynamicModel,
    *,
    model_path: Path | None = None,
    device: str | None = None,
) -> Reestimation:
    """Write to ``target`` what the service running ``model`` would record replaying ``source``.

    ``source``: the recording, or a :class:`SessionReader` already open on it. See the module
    docstring. Raise DataError for an unreadable source, a primary device
    without joint states or with another joint count than the model's, an unwritable target,
    or a model that gives non-finite estimates more than :data:`MAX_ERRORS` times.
    """
    started_s = time.perf_counter()
    reader = source if isinstance(source, SessionReader) else SessionReader(source)
    source, target = reader.path, Path(target)
    if target.exists() and target.resolve() == source.resolve():
        raise DataError("the re-estimated recording cannot overwrite its source", path=target)
    device = primary_device(reader, device)
    js_key = reader.stream_topic(device, MEASURED_JS)
    topics = replayed_topics(reader)
    if js_key is None or js_key not in topics:
        raise DataError(f"no joint states of {device!r} to re-estimate", path=source)
    ros_topics.validate_device(device)
    arrays = read_joint_state_arrays(source, js_key)
    if arrays.n_joints != model.n_joints:
        raise DataError(
            f"{js_key} has {arrays.n_joints} joints, the model has {model.n_joints}",
            path=source,
        )
    run = _run_service(model, js_key, arrays)
    metadata = {
        "primary_device": device,
        "source": "replay",
        "robot": model.robot,
        "friction": model.friction.kind,
        "model": "" if model_path is None else str(model_path),
        "recorder": __name__,
        "reestimated_from": str(source),
    }
    master = reader.metadata.get("master_device")
    if master:
        metadata["master_device"] = master
    with SessionWriter(target, metadata, profile="ros2") as writer:
        everything = np.ones(run.plausible.shape, dtype=bool)  # recorded as received
        replayed, first_log, last_log, written = _copy(reader, writer, topics, js_key, everything)
        written += _write_estimates(writer, device, run, arrays.seq, arrays.log_time_ns)
    span = 0.0 if first_log is None or last_log is None else (last_log - first_log) * 1e-9
    duration = time.perf_counter() - started_s
    stats = _service_stats(model, model_path, device, run, target, written, duration)
    return Reestimation(
        device, source, target, replayed, written, round(span, 6), round(duration, 6), stats
    )


def _copy(
    reader: SessionReader,
    writer: SessionWriter,
    topics: list[str],
    js_key: str,
    recorded: np.ndarray,
) -> tuple[dict[str, int], int | None, int | None, int]:
    """Copy the replayed messages to ``writer`` (of ``js_key`` only the ``recorded`` ones).

    A ROS 2 session chunk by chunk (:meth:`SessionWriter.copy_from`), without a Python object
    per message; an older one as :func:`_copy_replayed`. Return the messages read per ROS 2
    topic, the first and last log time and the messages written.
    """
    if not check_one_kind(reader, topics):
        return _copy_replayed(reader, writer, topics, js_key, recorded)
    copied = writer.copy_from(reader.path, topics, keep={js_key: recorded})
    return copied.read, copied.first_log_time_ns, copied.last_log_time_ns, copied.written


def _copy_replayed(
    reader: SessionReader,
    writer: SessionWriter,
    topics: list[str],
    js_key: str,
    recorded: np.ndarray,
) -> tuple[dict[str, int], int | None, int | None, int]:
    """Copy the replayed messages to ``writer`` (of ``js_key`` only the ``recorded`` ones).

    Message by message (the reference :func:`_copy` is checked against): ROS 2 channels as
    recorded, older ones encoded as a replay publishes them, on their ROS 2 topics. Return the
    messages read per ROS 2 topic, the first and last log time and the messages written.
    """
    names = {topic: ros2_topic(topic) for topic in topics}
    replayed = dict.fromkeys(names.values(), 0)
    first_log: int | None = None
    last_log: int | None = None
    written = 0
    js_index = 0
    if check_one_kind(reader, topics):
        rows = ((raw.topic, raw.log_time_ns, raw) for raw in reader.raw_messages(topics))
    else:
        rows = ((t, log_ns, message) for t, log_ns, message in reader.messages(topics))
    for topic, log_ns, item in rows:
        replayed[names[topic]] += 1
        if first_log is None:
            first_log = log_ns
        last_log = log_ns
        if topic == js_key:
            js_index += 1
            if not recorded[js_index - 1]:
                continue
        if isinstance(item, RawMessage):
            writer.write_ros2(topic, item.schema_name, item.data, item.sequence,
                              item.publish_time_ns, log_ns)  # fmt: skip
        else:
            try:
                encoded = ros2_payload(item)
            except (MessageError, ConfigurationError) as exc:
                raise DataError(f"cannot record {topic}: {exc}", path=reader.path) from None
            if encoded is None:
                raise DataError(f"cannot record {topic}: not a message", path=reader.path)
            writer.write_ros2(names[topic], encoded[0], encoded[1], item.seq, item.t_ns, log_ns)
        written += 1
    return replayed, first_log, last_log, written


def _run_service(model: DynamicModel, key: str, arrays: JointStateArrays) -> _ServiceRun:
    """Apply the service's input rules to the joint states of ``key`` and estimate in batch."""
    seq, t_ns, q_rad, effort_nm = arrays.seq, arrays.t_ns, arrays.q_rad, arrays.effort_nm
    qd_rad_s = arrays.qd_rad_s
    limit = MAX_ABS_JOINT_VALUE
    plausible = (
        (np.abs(q_rad) <= limit).all(axis=1)
        & (np.abs(qd_rad_s) <= limit).all(axis=1)
        & (np.abs(effort_nm) <= limit).all(axis=1)
    )
    malformed = MalformedCounter()
    for k in np.flatnonzero(~plausible).tolist():
        # the service's words for it
        malformed.count(key, MessageError(f"a value is beyond +-{limit:g} (seq {int(seq[k])})"))
    counters = JointStateCounters()
    tracker = counters.seqs
    candidates = np.flatnonzero(plausible)
    duplicate = np.zeros(candidates.size, dtype=bool)
    restarted = np.zeros(candidates.size, dtype=bool)
    for i, s in enumerate(seq[candidates].tolist()):
        event = tracker.observe(s)
        duplicate[i] = event.duplicate
        restarted[i] = event.restarted
    estimated = candidates[~duplicate]
    restarted = restarted[~duplicate]
    stamps = t_ns[estimated].tolist()
    estimator = BatchEstimator(model)
    q, tau = q_rad[estimated], effort_nm[estimated]
    published = np.ones(estimated.size, dtype=bool)
    clock = StreamClock()
    done = 0
    parts: list[BatchEstimates] = []
    errors = 0
    last_error = ""
    while done < estimated.size:
        saved = copy.copy(clock)
        starts, times = _advance(clock, stamps, restarted, done)
        result = estimator.estimate(times, q[done:], tau[done:], starts)
        bad = _unpublishable(result)
        if bad.size == 0:
            parts.append(result)
            break
        e = int(bad[0])
        errors += 1
        last_error = f"non-finite estimate at seq {int(seq[estimated[done + e]])}"
        if errors > MAX_ERRORS:
            raise DataError(f"the model gives non-finite estimates ({last_error}, and more)")
        parts.append(result.rows(slice(e + 1)))
        published[done + e] = False
        clock = saved  # the clock as it was after sample done + e, then reset (the service's)
        _advance(clock, stamps[: done + e + 1], restarted, done)
        clock.reset()
        done += e + 1
    return _ServiceRun(
        estimated, seq[estimated], published, _concatenate(parts, model.n_joints), plausible,
        counters, malformed, clock.restarts, errors, last_error,
    )  # fmt: skip


def _advance(
    clock: StreamClock, stamps: list[int], restarted: np.ndarray, start: int
) -> tuple[np.ndarray, np.ndarray]:
    """Run ``clock`` over ``stamps[start:]``: the stream starts (relative) and the times [s]."""
    starts = []
    times = np.empty(len(stamps) - start)
    flags = restarted.tolist()
    for i in range(start, len(stamps)):
        if clock.advance(stamps[i], flags[i]):
            starts.append(i - start)
        times[i - start] = clock.t_s
    return np.asarray(starts, dtype=np.int64), times


def _unpublishable(result: BatchEstimates) -> np.ndarray:
    """Rows whose estimate the service would count as an error (non-finite), in order."""
    joint_space = np.concatenate(
        (result.tau_external_nm, result.tau_motor_filtered_nm, result.tau_model_filtered_nm,
         result.coverage_weight),
        axis=1,
    )  # fmt: skip
    ok = np.isfinite(joint_space.sum(axis=1)) & ~np.isinf(result.force_tip_in_base_n).any(axis=1)
    return np.flatnonzero(~ok)


def _concatenate(parts: list[BatchEstimates], n: int) -> BatchEstimates:
    """Stack the rows of ``parts`` (no part: no rows)."""
    if not parts:
        empty = np.zeros((0, n))
        return BatchEstimates(
            np.zeros(0), np.zeros((0, 3)), empty, empty, empty, empty,
            np.zeros((0, n), dtype=bool), np.zeros(0, dtype=bool),
        )  # fmt: skip
    if len(parts) == 1:
        return parts[0]
    fields = BatchEstimates.__dataclass_fields__
    return BatchEstimates(*(np.concatenate([getattr(p, name) for p in parts]) for name in fields))


def _write_estimates(
    writer: SessionWriter,
    device: str,
    run: _ServiceRun,
    seq: np.ndarray,
    log_time_ns: np.ndarray,
) -> int:
    """Write the estimates as the service would have recorded them; return the messages.

    Two per estimate (WrenchStamped, EstimateDiagnostics), built with numpy from one encoded
    by :func:`~teleop_force.ros2.codec.encode_estimate`: MCAP sequence = the count of
    estimates published (from 1), ``source_sequence`` the joint state's, stamp, publish and
    log time the joint state's recorded log time.
    """
    from teleop_force.ros2 import codec  # rosbags: when re-estimating

    rows = np.flatnonzero(run.published)
    if rows.size == 0:
        return 0
    est = run.estimates
    n = est.tau_external_nm.shape[1]
    logs = log_time_ns[run.estimated[rows]]
    values = EstimateRows(
        t_ns=logs,
        source_sequence=seq[run.estimated[rows]].astype(np.int64),
        force_n=est.force_tip_in_base_n[rows],
        tau_ext_nm=est.tau_external_nm[rows],
        coverage_weight=est.coverage_weight[rows],
        on_trained_ground=est.on_trained_ground[rows],
        tau_motor_filtered_nm=est.tau_motor_filtered_nm[rows],
        tau_model_filtered_nm=est.tau_model_filtered_nm[rows],
    )
    zeros = (0.0,) * n
    template = m.ForceEstimateMessage(0, 0, 0, (0.0,) * 3, zeros, (False,) * n, zeros, zeros,
                                      zeros)  # fmt: skip
    names = ros_topics.model_joint_names(n)
    try:
        wrench, diagnostics = codec.encode_estimate(template, names, ros_topics.BASE_FRAME)
        wrenches, reports = estimate_blocks(wrench, diagnostics, values)
    except MessageError as exc:
        raise DataError(f"cannot record the estimates: {exc}", path=writer.path) from None
    counter = np.arange(1, rows.size + 1, dtype=np.int64)
    for topic, block in ((ros_topics.ESTIMATED_CF, wrenches),
                         (ros_topics.ESTIMATE_DIAGNOSTICS, reports)):  # fmt: skip
        for start in range(0, rows.size, _WRITE_BATCH):
            part = slice(start, start + _WRITE_BATCH)
            writer.write_ros2_block(ros_topics.topic_name(device, topic), topic.ros_type,
                                    block[part], counter[part], logs[part], logs[part])  # fmt: skip
    return 2 * int(rows.size)


def _service_stats(
    model: DynamicModel,
    model_path: Path | None,
    device: str,
    run: _ServiceRun,
    target: Path,
    written: int,
    duration_s: float,
) -> dict[str, Any]:
    """Return the ``service/stats`` JSON the service would report after the replay.

    Batch figures: latency and processing histograms are empty (nothing was published),
    rates are 0.
    """
    est = run.estimates
    published = run.published
    n = model.n_joints
    count = int(published.sum())
    on_ground = est.on_trained_ground[published]
    singular = int(est.singular[published].sum())
    last = None
    if count:
        row = int(np.flatnonzero(published)[-1])
        last = {
            "source_seq": int(run.source_seq[row]),
            "f_n": [None if math.isnan(x) else x for x in est.force_tip_in_base_n[row].tolist()],
        }
    empty = {"p50": None, "p99": None, "max": None, "count": 0}
    return {
        "role": "service",
        "device": device,
        "model": {
            "path": None if model_path is None else str(model_path),
            "robot": model.robot,
            "friction": model.friction.kind,
            "loads": 0,
        },
        "uptime_s": round(duration_s, 3),
        "joint_states": run.joint_states.to_dict(stream_restarts=run.stream_restarts, backlog=0),
        "estimates": {
            "published": count,
            "singular": singular,
            "errors": run.errors,
            "last_error": run.last_error,
        },
        # the live service's keys; a recording holds no attachments to miss
        "malformed": {**run.malformed.to_dict(), "without_attachment": 0},
        "latency_ms": dict(empty),
        "processing_ms": dict(empty),
        "on_ground_fraction": _fraction(int(on_ground.all(axis=1).sum()), count),
        "on_ground_fraction_per_joint": [
            _fraction(int(c), count) for c in on_ground.sum(axis=0).tolist()
        ] if count else [None] * n,
        "adaptation": {"enabled": False, "available": False, "note": "batch: fixed model",
                       "samples": 0},
        "recording": None,
        "last_recording": {
            "path": str(target), "messages": written, "durable": written, "backlog": 0,
            "dropped": 0,
        },
        "memory": None,
        "controls": {"requests": 0, "refused": 0, "last_refusal": ""},
        "last_estimate": last,
        "residual_watch": None,  # batch: no live watch
        "zenoh_floor": None,
    }  # fmt: skip


def _fraction(count: int, total: int) -> float | None:
    return None if total == 0 else round(count / total, 6)
