"""The commands that run whole recordings in batch: the streaming estimator's numbers, faster.

``estimate``, ``evaluate`` and ``replay --with-service --record`` (re-estimation) must give
what the streaming estimator (and the force service's rules) give sample by sample, with the
documented outputs and JSON keys (docs/cli.md).
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from teleop_force.cli.main import main
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.least_squares import relative_rms
from teleop_force.io.interchange_csv import Recording, write_interchange_csv
from teleop_force.io.mcap_session import SessionReader, SessionWriter
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.service import reestimation
from teleop_force.service.force_service import MAX_ABS_JOINT_VALUE
from teleop_force.service.stream_clock import StreamClock
from teleop_force.simulation import palpation_protocol
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.stream_stats import SequenceTracker

EPOCH_NS = 1_700_000_000_000_000_000
SLAVE_JS, SLAVE_ESTIMATES = "/slave/measured_js", "/slave/estimated_cf"
#: The top-level keys of ``replay --json`` (docs/cli.md), ``service`` with --with-service.
REPLAY_KEYS = {"device", "published", "duration_s", "recorded_span_s", "matched", "stopped"}
ESTIMATE_FIELDS = (
    "f_n", "tau_ext_nm", "coverage_weight", "tau_motor_filtered_nm", "tau_model_filtered_nm",
)  # fmt: skip


@pytest.fixture(scope="module")
def model() -> DynamicModel:
    """The shipped model (a wavelet network with its coverage blend)."""
    return DynamicModel.load(DEFAULT_MODEL_PATH)


@pytest.fixture(scope="module")
def palpation():
    session = palpation_protocol(2.5, seed=7)
    return (
        np.asarray(session.t_s),
        np.asarray(session.q_rad),
        np.asarray(session.qd_true_rad_s),
        np.asarray(session.tau_nm),
        np.asarray(session.f_tip_in_base_n),
    )


def _streamed(model, t, q, tau):
    estimator = ForceEstimator(model)
    return [estimator.update(t[k], q[k], tau[k]) for k in range(t.size)]


def test_estimate_writes_the_streaming_estimates(tmp_path, model, palpation) -> None:
    t, q, _, tau, force = palpation
    data = tmp_path / "rec.csv"
    write_interchange_csv(data, Recording(t, q, tau, force))
    out = tmp_path / "forces.csv"
    assert main(["estimate", str(DEFAULT_MODEL_PATH), str(data), "-o", str(out)]) == 0
    forces = np.array([e.force_tip_in_base_n for e in _streamed(model, t, q, tau)])
    written = out.read_text().splitlines()
    assert written[0] == "t,f_x,f_y,f_z" and len(written) == t.size + 1
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    # %.17g: every double read back exactly (the times are the recording's own)
    np.testing.assert_array_equal(table[:, 0], t)
    # the batch form equals the streaming step to 1e-9 (docs/architecture.md)
    np.testing.assert_allclose(table[:, 1:], forces, rtol=0, atol=1e-9)


def test_estimate_of_an_unwritable_output_exits_2(tmp_path, palpation, capsys) -> None:
    t, q, _, tau, _ = palpation
    data = tmp_path / "rec.csv"
    write_interchange_csv(data, Recording(t[:50], q[:50], tau[:50]))
    out = tmp_path / "missing" / "forces.csv"
    assert main(["estimate", str(DEFAULT_MODEL_PATH), str(data), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "forces.csv" in err[0]


def test_evaluate_reports_the_streaming_torques(tmp_path, model, palpation, capsys) -> None:
    t, q, _, tau, _ = palpation
    paths = []
    for i, rows in enumerate((slice(0, 1500), slice(1000, 2500))):
        path = tmp_path / f"part{i}.csv"
        write_interchange_csv(path, Recording(t[rows] - t[rows][0], q[rows], tau[rows]))
        paths.append(path)
    assert main(["evaluate", str(DEFAULT_MODEL_PATH), *map(str, paths), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert set(payload) == {
        "relative_rms", "samples", "coverage", "friction", "robot", "estimator", "count_observer",
    }  # fmt: skip
    assert payload["count_observer"] is True  # the shipped model's
    measured, estimated, on_ground = [], [], []
    for rows in (slice(0, 1500), slice(1000, 2500)):
        tr = t[rows] - t[rows][0]
        streamed = _streamed(model, tr, q[rows], tau[rows])
        valid = tr >= model.filter_config.warmup_s
        measured += [e.tau_motor_filtered_nm for e, v in zip(streamed, valid, strict=True) if v]
        estimated += [e.tau_model_filtered_nm for e, v in zip(streamed, valid, strict=True) if v]
        on_ground += [e.on_trained_ground for e, v in zip(streamed, valid, strict=True) if v]
    expected = relative_rms(np.array(measured), np.array(estimated))
    np.testing.assert_allclose(payload["relative_rms"], expected, rtol=1e-9)
    assert payload["samples"] == len(measured)
    np.testing.assert_allclose(payload["coverage"], np.mean(on_ground, axis=0), rtol=1e-12)
    assert payload["friction"] == "wn" and payload["robot"] == "omni"


def test_evaluate_names_a_recording_of_another_joint_count(tmp_path, capsys) -> None:
    path = tmp_path / "two.csv"
    t = np.arange(20) * 1e-3
    write_interchange_csv(path, Recording(t, np.zeros((20, 2)), np.zeros((20, 2))))
    assert main(["evaluate", str(DEFAULT_MODEL_PATH), str(path)]) == 2
    assert "two.csv" in capsys.readouterr().err


# -- re-estimation ---------------------------------------------------------------------------


def _joint_states(palpation) -> list[tuple[int, m.JointState]]:
    """The slave's joint states with what the service must cope with: a duplicate, a value out
    of range, a sequence restart, a pause > 0.5 s and a stamp going back; and log times."""
    t, q, qd, tau, _ = palpation
    out = []
    seq_offset = 0
    stamp_offset = 0
    for k in range(t.size):
        if k == 900:
            seq_offset = 50_000_000 - k  # the sequence jumps: a new stream
        if k == 1400:
            stamp_offset += 700_000_000  # a pause
        if k == 1900:
            stamp_offset -= 40_000_000  # back in time
        stamp = EPOCH_NS + round(float(t[k]) * 1e9) + stamp_offset
        effort = tuple(tau[k].tolist())
        if k == 300:
            effort = (2e6, *effort[1:])  # out of range: malformed, dropped
        js = m.JointState(k + seq_offset, stamp, tuple(q[k].tolist()), tuple(qd[k].tolist()),
                          effort)  # fmt: skip
        out.append((EPOCH_NS + k * 1_000_000 + 50_000, js))
        if k == 600:  # the same message twice
            out.append((EPOCH_NS + k * 1_000_000 + 60_000, js))
    return out


def _write_recording(path: Path, palpation) -> list[tuple[int, m.JointState]]:
    t, _, _, _, force = palpation
    states = _joint_states(palpation)
    meta = {"primary_device": "slave", "master_device": "master", "source": "live"}
    with SessionWriter(path, meta) as writer:
        for k, (log_ns, js) in enumerate(states):
            stamp = js.t_ns
            master = m.JointState(k, stamp, js.q_rad, js.qd_rad_s, (0.0,) * len(js.q_rad))
            writer.write(keys.measured_js("master"), master, log_ns)
            writer.write(keys.setpoint_js("master"), m.JointSetpoint(k, stamp, js.q_rad), log_ns)
            writer.write(keys.measured_js("slave"), js, log_ns + 1)
            row = min(k, t.size - 1)
            contact = m.ContactForce(k, stamp, tuple(force[row].tolist()))
            writer.write(keys.measured_cf("slave"), contact, log_ns + 2)
            if k % 50 == 0:
                writer.write(
                    keys.status("slave"),
                    m.Status(k // 50, stamp, m.SafetyState.FOLLOWING),
                    log_ns + 3,
                )
            if k % 100 == 0:  # an old estimate: not replayed, replaced
                old = m.ForceEstimateMessage(
                    k, stamp, js.seq, (0.0, 0.0, 0.0), (0.0,) * 3, (True,) * 3, (1.0,) * 3,
                    (0.0,) * 3, (0.0,) * 3,
                )  # fmt: skip
                writer.write(keys.estimated_cf("slave"), old, log_ns + 4)
    return states


def _service_emulation(model, states, failing_seq: int | None = None):
    """The service's rules, one joint state at a time, with the streaming estimator.

    The estimate of ``failing_seq`` fails (non-finite): not published, the stream restarts.
    """
    tracker, clock, estimator = SequenceTracker(), StreamClock(), ForceEstimator(model)
    out = []
    for _, js in states:
        values = (*js.q_rad, *js.qd_rad_s, *js.effort_nm)
        if any(abs(x) > MAX_ABS_JOINT_VALUE for x in values):
            continue
        event = tracker.observe(js.seq)
        if event.duplicate:
            continue
        if clock.advance(js.t_ns, event.restarted):
            estimator.reset()
        estimate = estimator.update(clock.t_s, js.q_rad, js.effort_nm)
        if js.seq == failing_seq:
            clock.reset()
            continue
        out.append((js.seq, estimate))
    return out, tracker, clock


def test_reestimation_records_what_the_service_would(tmp_path, model, palpation, capsys) -> None:
    source = tmp_path / "live.mcap"
    states = _write_recording(source, palpation)
    target = tmp_path / "again.mcap"
    argv = ["replay", str(source), "--with-service", "--record", str(target), "--json"]
    assert main([*argv, "--model", str(DEFAULT_MODEL_PATH)]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert REPLAY_KEYS | {"service", "messages_per_s"} <= set(payload)
    expected, tracker, clock = _service_emulation(model, states)
    service = payload["service"]
    js_stats = service["joint_states"]
    assert js_stats["received"] == tracker.received == len(states) - 1
    assert js_stats["duplicates"] == 1 and js_stats["restarts"] == tracker.restarts == 1
    assert js_stats["stream_restarts"] == clock.restarts == 3
    assert service["estimates"]["published"] == len(expected)
    assert service["malformed"]["dropped"] == 1
    assert payload["published"][SLAVE_JS] == len(states)
    assert SLAVE_ESTIMATES not in payload["published"]

    reader = SessionReader(target)
    assert reader.metadata["primary_device"] == "slave"
    assert reader.metadata["source"] == "replay"
    counts = reader.message_counts
    assert counts[SLAVE_JS] == len(states)  # as received: the malformed one too
    for topic in ("/master/measured_js", "/master/setpoint_js", "/slave/true_cf"):
        assert counts[topic] == len(states)
    assert counts["/slave/estimate_diagnostics"] == counts[SLAVE_ESTIMATES] == len(expected)
    estimates = [e for _, _, e in reader.messages([SLAVE_ESTIMATES])]
    assert [e.seq for e in estimates] == list(range(1, len(expected) + 1))  # as published
    assert [e.source_seq for e in estimates] == [seq for seq, _ in expected]
    logs: dict[int, int] = {}
    for log, js in states:
        logs.setdefault(js.seq, log + 1)  # a duplicate gets no estimate
    assert [e.t_ns for e in estimates] == [logs[seq] for seq, _ in expected]
    for got, (_, want) in zip(estimates, expected, strict=True):
        np.testing.assert_allclose(got.f_n, want.force_tip_in_base_n, atol=1e-9, rtol=0)
        np.testing.assert_allclose(got.tau_ext_nm, want.tau_external_nm, atol=1e-9, rtol=0)
        np.testing.assert_allclose(got.coverage_weight, want.coverage_weight, atol=1e-9, rtol=0)
        np.testing.assert_allclose(
            got.tau_model_filtered_nm, want.tau_model_filtered_nm, atol=1e-9, rtol=0
        )
        np.testing.assert_allclose(
            got.tau_motor_filtered_nm, want.tau_motor_filtered_nm, atol=1e-9, rtol=0
        )
        assert got.on_trained_ground == tuple(want.on_trained_ground.tolist())


def test_a_failed_estimate_restarts_the_stream_as_the_service_does(
    tmp_path, model, palpation, capsys, monkeypatch
) -> None:
    source = tmp_path / "live.mcap"
    states = _write_recording(source, palpation)
    # a joint state in motion, whose angles no other sample has: the one that fails
    angles = [js.q_rad for _, js in states]
    failing = next(js for _, js in states[700:] if angles.count(js.q_rad) == 1)
    failing_seq, marker = failing.seq, failing.q_rad
    original = reestimation.BatchEstimator.estimate

    def failing(self, t_s, q_rad, tau_nm, stream_starts=None):
        result = original(self, t_s, q_rad, tau_nm, stream_starts)
        rows = np.flatnonzero((np.asarray(q_rad) == marker).all(axis=1))
        result.tau_model_filtered_nm[rows] = np.nan  # the service counts it as an error
        return result

    monkeypatch.setattr(reestimation.BatchEstimator, "estimate", failing)
    target = tmp_path / "again.mcap"
    argv = ["replay", str(source), "--with-service", "--record", str(target), "--json"]
    assert main([*argv, "--model", str(DEFAULT_MODEL_PATH)]) == 0
    service = json.loads(capsys.readouterr().out)["service"]
    assert service["estimates"]["errors"] == 1
    assert f"seq {failing_seq}" in service["estimates"]["last_error"]
    expected, _, clock = _service_emulation(model, states, failing_seq)
    assert service["joint_states"]["stream_restarts"] == clock.restarts
    estimates = [e for _, _, e in SessionReader(target).messages([SLAVE_ESTIMATES])]
    assert [e.source_seq for e in estimates] == [seq for seq, _ in expected]
    for got, (_, want) in zip(estimates, expected, strict=True):
        np.testing.assert_allclose(got.f_n, want.force_tip_in_base_n, atol=1e-9, rtol=0)
        np.testing.assert_allclose(
            got.tau_model_filtered_nm, want.tau_model_filtered_nm, atol=1e-9, rtol=0
        )


def test_reestimation_refuses_a_model_of_another_joint_count(tmp_path, capsys) -> None:
    source = tmp_path / "live.mcap"
    with SessionWriter(source, {"primary_device": "slave"}) as writer:
        for k in range(10):
            js = m.JointState(k, EPOCH_NS + k * 1_000_000, (0.1, 0.2), (0.0, 0.0), (0.0, 0.0))
            writer.write(keys.measured_js("slave"), js, EPOCH_NS + k * 1_000_000)
    argv = ["replay", str(source), "--with-service", "--record", str(tmp_path / "x.mcap")]
    assert main(argv) == 2
    assert "2 joints" in capsys.readouterr().err


def test_over_zenoh_needs_a_recording(tmp_path, capsys) -> None:
    source = tmp_path / "none.mcap"
    assert main(["replay", str(source), "--with-service", "--over-zenoh"]) == 2
    assert "--over-zenoh" in capsys.readouterr().err


@pytest.mark.zenoh
def test_batch_reestimation_equals_the_live_service(tmp_path, model, palpation, capsys) -> None:
    """The same recording through the service over Zenoh, and in batch: the same estimates."""
    source = tmp_path / "live.mcap"
    _write_recording(source, palpation)
    live, batch = tmp_path / "live_again.mcap", tmp_path / "batch_again.mcap"
    common = ["replay", str(source), "--with-service", "--model", str(DEFAULT_MODEL_PATH)]
    assert main([*common, "--record", str(live), "--over-zenoh", "--fast", "--json"]) == 0
    live_payload = json.loads(capsys.readouterr().out)
    assert live_payload["messages_per_s"] > 0.0
    assert main([*common, "--record", str(batch), "--json"]) == 0
    batch_payload = json.loads(capsys.readouterr().out)
    # the batch service reports what the live one does (counters), under the same keys
    assert set(batch_payload) >= set(live_payload)
    assert set(batch_payload["service"]) == set(live_payload["service"])
    for part in ("joint_states", "estimates", "malformed"):
        assert set(batch_payload["service"][part]) == set(live_payload["service"][part])
    for name in ("received", "lost", "restarts", "duplicates", "stream_restarts"):
        assert (
            batch_payload["service"]["joint_states"][name]
            == live_payload["service"]["joint_states"][name]
        ), name
    assert batch_payload["service"]["estimates"] == live_payload["service"]["estimates"]

    def estimates(path):
        reader = SessionReader(path)
        return [e for _, _, e in reader.messages([SLAVE_ESTIMATES])]

    a, b = estimates(live), estimates(batch)
    assert len(a) == len(b) > 2000
    assert [e.source_seq for e in a] == [e.source_seq for e in b]
    assert [e.seq for e in a] == [e.seq for e in b]
    for x, y in zip(a, b, strict=True):
        for name in ESTIMATE_FIELDS:
            u, v = getattr(x, name), getattr(y, name)
            assert all(
                (math.isnan(p) and math.isnan(r)) or abs(p - r) <= 1e-9
                for p, r in zip(u, v, strict=True)
            ), (x.source_seq, name, u, v)
        assert x.on_trained_ground == y.on_trained_ground
    counts_live = SessionReader(live).message_counts
    counts_live.pop("/slave/service/diagnostics", None)  # the live residual watch's, 1 Hz
    assert SessionReader(batch).message_counts == counts_live
