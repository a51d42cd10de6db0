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

The new recording holds every recorded joint state (of every device), setpoint, true contact
force and status, with their recorded log times, and one ``estimated_cf`` per estimate:
``seq`` counts the estimates published (from 0), ``source_seq`` is the joint state's ``seq``,
exactly as live. What differs from a live run: nothing is published over Zenoh, the
messages keep their recorded stamps (a replay over Zenoh shifts them to the present), and an
estimate's ``t_ns`` (its publish time, which no offline computation has) is its joint state's
recorded log time, the time the recording service received it, so latencies read off the new
recording are the slave-to-service transport alone. The model is fixed: no online adaptation.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from teleop_force.errors import DataError, MessageError
from teleop_force.estimation.batch import BatchEstimates, BatchEstimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.cdr_columns import JointStateArrays
from teleop_force.io.mcap_session import SessionReader, SessionWriter, read_joint_state_arrays
from teleop_force.io.replay import primary_device, replayed_topics
from teleop_force.service.counters import JointStateCounters, MalformedCounter
from teleop_force.service.force_service import MAX_ABS_JOINT_VALUE, SEQ_MASK
from teleop_force.service.stream_clock import StreamClock
from teleop_force.transport import keys
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
    plausible: np.ndarray  # mask over the joint states: recorded (not malformed)
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
    js_key = keys.measured_js(device)
    topics = replayed_topics(reader)
    if js_key not in topics:
        raise DataError(f"no joint states of {device!r} ({js_key}) to re-estimate", path=source)
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
    estimate_key = keys.estimated_cf(device)
    with SessionWriter(target, metadata) as writer:
        replayed, first_log, last_log, written = _copy(
            reader, writer, topics, js_key, run.plausible
        )
        written += _write_estimates(writer, estimate_key, run, arrays.seq, arrays.log_time_ns)
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

    Chunk by chunk (:meth:`SessionWriter.copy_from`): the messages :func:`_copy_replayed`
    writes, without a Python object per message. Return the messages read per topic, the
    first and last log time and the messages written.
    """
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

    Message by message (the reference :func:`_copy` is checked against). Return the messages
    read per topic, the first and last log time and the messages written.
    """
    replayed = dict.fromkeys(topics, 0)
    first_log: int | None = None
    last_log: int | None = None
    written = 0
    batch_topics: list[str] = []
    batch_payloads: list[bytes] = []
    batch_logs: list[int] = []
    js_index = 0
    for topic, log_ns, message in reader.messages(topics):
        replayed[topic] += 1
        if first_log is None:
            first_log = log_ns
        last_log = log_ns
        if topic == js_key:
            js_index += 1
            if not recorded[js_index - 1]:
                continue
        batch_topics.append(topic)
        batch_payloads.append(message.encode())
        batch_logs.append(log_ns)
        if len(batch_topics) >= _WRITE_BATCH:
            written += _write(writer, batch_topics, batch_payloads, batch_logs)
            batch_topics, batch_payloads, batch_logs = [], [], []
    written += _write(writer, batch_topics, batch_payloads, batch_logs)
    return replayed, first_log, last_log, written


def _write(writer: SessionWriter, topics: list[str], payloads: list[bytes], logs: list[int]) -> int:
    """Write a batch of payloads; return how many (DataError if one is refused)."""
    if not topics:
        return 0
    rejected = writer.write_payloads(topics, payloads, logs)
    if rejected:
        index, error = rejected[0]
        raise DataError(f"cannot record {topics[index]}: {error}", path=writer.path)
    return len(topics)


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
    key: str,
    run: _ServiceRun,
    seq: np.ndarray,
    log_time_ns: np.ndarray,
) -> int:
    """Write the estimates as the service would have recorded them; return how many.

    ``seq`` counts the estimates published, ``source_seq`` is the joint state's, and the
    publish time ``t_ns`` (and log time) is the joint state's recorded log time.
    """
    rows = np.flatnonzero(run.published)
    sources = seq[run.estimated[rows]]
    logs = log_time_ns[run.estimated[rows]]
    payloads = _estimate_payloads(run.estimates, rows, sources, logs)
    logs_list = logs.tolist()
    written = 0
    for start in range(0, len(payloads), _WRITE_BATCH):
        stop = start + _WRITE_BATCH
        part = payloads[start:stop]
        written += _write(writer, [key] * len(part), part, logs_list[start:stop])
    return written


def _estimate_payloads(
    est: BatchEstimates, rows: np.ndarray, source_seq: np.ndarray, t_ns: np.ndarray
) -> list[bytes]:
    """Return the wire ForceEstimate of each of ``rows`` of ``est``, built with numpy.

    The bytes of :func:`~teleop_force.transport.messages.pack_force_estimate` (``seq``
    counting from 0, ``t_ns`` and ``source_seq`` given per row), without a call per row.
    """
    n = est.tau_external_nm.shape[1]
    layout = np.dtype(
        [("magic", "S2"), ("version", "u1"), ("type", "u1"), ("seq", "<u4"), ("t_ns", "<i8"),
         ("source_seq", "<u4"), ("n", "u1"), ("values", "<f8", (3 + 4 * n,)),
         ("mask", "u1", ((n + 7) // 8,))]
    )  # fmt: skip
    block = np.empty(rows.size, dtype=layout)
    block["magic"] = m.MAGIC
    block["version"] = m.VERSION
    block["type"] = int(m.MessageType.FORCE_ESTIMATE)
    block["seq"] = np.arange(rows.size, dtype=np.int64) & SEQ_MASK
    block["t_ns"] = t_ns
    block["source_seq"] = source_seq
    block["n"] = n
    block["values"] = np.concatenate(
        (est.force_tip_in_base_n[rows], est.tau_external_nm[rows], est.coverage_weight[rows],
         est.tau_motor_filtered_nm[rows], est.tau_model_filtered_nm[rows]),
        axis=1,
    )  # fmt: skip
    block["mask"] = np.packbits(est.on_trained_ground[rows], axis=1, bitorder="little")
    raw = block.tobytes()
    width = layout.itemsize
    return [raw[i : i + width] for i in range(0, len(raw), width)]


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
        "malformed": run.malformed.to_dict(),
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
