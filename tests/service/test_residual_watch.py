"""The live residual watch on simulated streams: quiet on clean sessions, fires on a change.

The streams are made as the live system makes them (``master_slave.watched_streams``): the
simulated Omni under the PID along the palpation script, the service's estimator, the
fixed-layout records the service appends to the watch's ring, the watch evaluated every second
of stream time as the service's thread does; its reports go out as ROS 2 ServiceDiagnostics.
"""

from __future__ import annotations

import math
import time
import tracemalloc

import numpy as np
import pytest

from master_slave.slave import EffectSwitch, calibrated_effect
from master_slave.watched_streams import T0_NS, watched_session
from teleop_force.errors import ConfigurationError, MessageError
from teleop_force.ros2 import codec
from teleop_force.service.residual_watch import (
    PayloadRing,
    ResidualWatch,
    Rows,
    WatchConfig,
    _block_mean,
    _match,
    append_cost_ns,
    decode_samples,
)
from teleop_force.transport import messages as m

# -- the ring and the decoding ---------------------------------------------------------------


def test_ring_keeps_the_newest_and_refuses_what_was_overwritten() -> None:
    ring = PayloadRing(1024)
    for k in range(3000):
        ring.append(bytes([k % 256]), bytes([k % 7]))
    assert ring.count == 3000
    js, est = ring.read(2000, 3000)  # type: ignore[misc]
    assert len(js) == 1000 and js[0] == bytes([2000 % 256]) and est[-1] == bytes([2999 % 7])
    assert ring.read(1000, 3000) is None  # lapped
    with pytest.raises(ConfigurationError):
        PayloadRing(1000)


def test_decode_samples_reads_the_ring_record_layouts() -> None:
    js = [m.pack_joint_state(5 + k, T0_NS + k * 10**6, [0.1 * k, 0.2, 0.3], [0.0] * 3,
                             [1.0, 2.0, 3.0]) for k in range(4)]  # fmt: skip
    values = [7.0, 8.0, 9.0, 0.01, 0.02, 0.03, 1.0, 1.0, 1.0, 0.5, 0.6, 0.7, 0.4, 0.4, 0.4]
    est = [m.pack_force_estimate(k, T0_NS, 5 + k, 3, values, 7) for k in range(4)]
    s = decode_samples(js, est, 3, 100, T0_NS)
    assert s.index.tolist() == [100, 101, 102, 103]
    assert s.t_s.tolist() == pytest.approx([0.0, 1e-3, 2e-3, 3e-3])
    assert s.seq.tolist() == [5, 6, 7, 8]
    assert s.q_rad[3].tolist() == pytest.approx([0.3, 0.2, 0.3])
    assert s.effort_nm[2].tolist() == [1.0, 2.0, 3.0]  # the joint state's torques
    assert s.force_n[0].tolist() == [7.0, 8.0, 9.0]
    assert s.tau_ext_nm[0].tolist() == [0.01, 0.02, 0.03]
    assert s.tau_motor_nm[0].tolist() == [0.5, 0.6, 0.7]  # not the coverage weights
    with pytest.raises(MessageError):
        decode_samples(js, [*est[:3], est[3][:-1]], 3, 0, T0_NS)


def test_append_stores_references_and_allocates_nothing() -> None:
    # the hot path's contract, checked without a clock (benchmarks/watch_offline.py prints
    # append_cost_ns): the payloads are kept by reference, and appending allocates no memory
    # that stays (no growing list, no copy of a payload)
    watch = ResidualWatch(3, WatchConfig(ring_capacity=1024))
    pairs = [(bytes(40) + k.to_bytes(4, "little"), bytes(150) + k.to_bytes(4, "little"))
             for k in range(5000)]  # fmt: skip
    append = watch.append
    for a, b in pairs[:2000]:  # fill the ring once: every slot holds a payload
        append(a, b)
    tracemalloc.start()
    try:
        before = tracemalloc.take_snapshot()
        for a, b in pairs[2000:]:
            append(a, b)
        after = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    grown = sum(d.size_diff for d in after.compare_to(before, "filename") if d.size_diff > 0)
    assert grown < 4096, grown  # 3000 appends of ~200-byte payloads would be ~600 kB
    assert watch.ring.count == 5000
    k = watch.ring.count - 1
    assert watch.ring._joint_states[k & 1023] is pairs[k][0]
    assert watch.ring._estimates[k & 1023] is pairs[k][1]


def test_append_cost_ns_reports_a_figure() -> None:
    # the figure itself is a benchmark's (not asserted here): only that it is one
    cost = append_cost_ns(2_000)
    assert math.isfinite(cost)


def test_config_refuses_out_of_range_values() -> None:
    with pytest.raises(ConfigurationError):
        WatchConfig(window_s=0.0)
    with pytest.raises(ConfigurationError):
        WatchConfig(alpha=1.5)
    with pytest.raises(ConfigurationError):
        WatchConfig(persistence=0)
    with pytest.raises(ConfigurationError):
        WatchConfig(ring_capacity=3000)
    with pytest.raises(ConfigurationError):
        EffectSwitch("no-such-effect")


# -- the diagnostics message -------------------------------------------------------------------


def test_diagnostics_round_trip_and_refuse_malformed() -> None:
    message = m.ServiceDiagnostics(
        seq=3, t_ns=T0_NS, device="slave", state="dependence", stream_s=70.0,
        baseline_complete=True, rms_torque_nm=(0.02, 0.15, 0.02),
        checks=(m.DiagnosticCheck(2, 300, "tau2", 1e-9, 0.11, 5),),
        finding=m.DiagnosticFinding(2, "tau2", 0.11, 0.017, 1e-9, 61.0, True),
        command="teleop-force residual RECORDING --model /m.json",
    )  # fmt: skip
    assert m.ServiceDiagnostics.decode(message.encode()) == message
    with pytest.raises(MessageError):
        m.ServiceDiagnostics.decode(b"{not json")
    with pytest.raises(MessageError):
        m.ServiceDiagnostics.decode(b'{"version": 1, "seq": 1}')
    with pytest.raises(MessageError):  # a finding needs its command
        m.ServiceDiagnostics(
            seq=0, t_ns=0, device="slave", state="dependence", stream_s=0.0,
            baseline_complete=True, rms_torque_nm=(), checks=(),
            finding=m.DiagnosticFinding(1, "t", 0.1, 0.01, 0.0, 1.0, True), command="",
        )  # fmt: skip


# -- the watch on simulated sessions --------------------------------------------------------


def test_quiet_on_a_clean_session_and_publishes_its_state() -> None:
    session = watched_session(120.0, seed=21)
    assert session.first_report_s is None, session
    assert session.states[-1] == "watching"
    assert "baseline" in session.states[:10]


def test_fires_within_30_s_of_a_load_dependent_friction_on_its_joint() -> None:
    # 30 % of the joint's RMS commanded torque over the session so far, contact included (the
    # demo's calibration); benchmarks/watch_offline.py reports the 10 % cases per seed. In
    # the palpation's free motion tau2 spans too little (about 0.06 N m) to tell a load
    # dependence from a level change in 30 s: the variable named is then ``t`` (changed since
    # the baseline), never another joint's angle.
    switch = EffectSwitch("load-friction", at_s=60.0, scale=0.3)
    session = watched_session(95.0, seed=22, switch=switch)
    assert session.switched_at_s == pytest.approx(60.0)
    assert session.first_report_s is not None, session
    assert session.first_report_s - 60.0 <= 30.0
    assert session.finding is not None and session.finding[0] == 2
    assert session.finding[1] in ("tau2", "t"), session.finding


def _rows(q: np.ndarray, qd: np.ndarray, tau_ext: np.ndarray, t0: float = 0.0) -> Rows:
    n = q.shape[0]
    return Rows(
        t_s=t0 + 0.02 * np.arange(n), run=np.zeros(n, dtype=np.int64), q_rad=q,
        qd_rad_s=qd, qdd_rad_s2=np.zeros_like(q), tau_motor_nm=np.zeros_like(q),
        tau_ext_nm=tau_ext, free=np.ones(q.shape, dtype=bool),
    )  # fmt: skip


def test_only_poses_the_baseline_visited_are_compared() -> None:
    rng = np.random.default_rng(3)
    # baseline: joint 1 between -0.2 and 0.2 rad, moving both ways; tau_ext = misfit(q1)
    qb = np.column_stack((rng.uniform(-0.2, 0.2, 400), np.zeros(400), np.zeros(400)))
    qdb = np.column_stack((rng.choice([-0.3, 0.3], 400), np.zeros(400), np.zeros(400)))
    misfit = 0.05 * np.sin(4.0 * qb[:, 0])
    base = _rows(qb, qdb, np.column_stack((misfit, np.zeros(400), np.zeros(400))))
    # window: half in the baseline's poses, half at 1 rad (never visited), same misfit + 0.01
    qc = np.column_stack((np.r_[rng.uniform(-0.1, 0.1, 50), np.full(50, 1.0)],
                          np.zeros(100), np.zeros(100)))  # fmt: skip
    qdc = np.column_stack((np.full(100, 0.3), np.zeros(100), np.zeros(100)))
    tau = 0.05 * np.sin(4.0 * qc[:, 0]) + 0.01
    current = _rows(qc, qdc, np.column_stack((tau, np.zeros(100), np.zeros(100))), t0=100.0)
    matched = _match(base, current, 0, radius_rad=0.15, least=5)
    assert matched is not None
    assert matched.keep[:50].all() and not matched.keep[50:].any()
    # the difference from the neighbours' mean is the change, up to the misfit's local slope
    # (the nuisance columns fit it): |misfit'| * radius = 0.2 * 0.15 at most
    assert np.all(np.abs(matched.difference - 0.01) < 0.03)
    assert abs(float(np.mean(matched.difference)) - 0.01) < 0.005
    assert matched.nuisance.shape == (50, 5)


def test_the_baseline_matched_with_itself_pairs_only_other_moves() -> None:
    # the baseline's own rows enter the test as rows without a change: each is compared with
    # baseline neighbours at least `apart_s` away in time, never with its own move (whose
    # noise is correlated with it). Two passes over the same angles, 10 s apart, each with its
    # own offset (+-0.01 N m): kept apart, each pass is compared with the other one only.
    n = 150
    q = np.column_stack((np.linspace(-0.45, 0.45, n), np.zeros(n), np.zeros(n)))
    qd = np.column_stack((np.full(n, 0.3), np.zeros(n), np.zeros(n)))
    offset = np.column_stack((np.ones(n), np.zeros(n), np.zeros(n))) * 0.01
    base = Rows.concat((_rows(q, qd, offset), _rows(q, qd, -offset, t0=10.0)))
    apart = _match(base, base, 0, radius_rad=0.15, least=5, apart_s=1.0)
    assert apart is not None and apart.rows > n  # most rows have the other pass near them
    first = apart.t_s < 5.0
    assert np.allclose(apart.difference[first], 0.02)
    assert np.allclose(apart.difference[~first], -0.02)
    alone = _match(base, base, 0, radius_rad=0.15, least=5)
    assert alone is not None and np.all(np.abs(alone.difference) < 0.015)


def test_rows_average_tau_ext_over_their_interval() -> None:
    x = np.arange(100.0)[:, None] * np.ones((1, 3))
    idx = np.array([20, 40])
    assert _block_mean(x, idx, 20)[:, 0].tolist() == pytest.approx([19.5, 39.5])


def test_reset_forgets_the_baseline_and_the_findings() -> None:
    watch = ResidualWatch(3, WatchConfig())
    watch.findings[0] = None  # type: ignore[assignment]
    watch.reset(model_path="/x/model.json")
    assert watch.findings == {} and watch.state == "baseline"
    assert watch.model_path == "/x/model.json"


def test_diagnostics_name_the_command_when_a_dependence_is_reported() -> None:
    watch = ResidualWatch(3, device="slave", model_path="/abs/model.json")
    js = m.pack_joint_state(0, T0_NS, [0.0] * 3, [0.0] * 3, [0.0] * 3)
    est = m.pack_force_estimate(0, T0_NS, 0, 3, [0.0] * 15, 7)
    watch.append(js, est)
    payload = watch.evaluate_and_encode()
    assert payload is not None
    message = m.ServiceDiagnostics.decode(payload)
    assert message.state == "baseline" and message.command == "" and message.finding is None
    from teleop_force.service.residual_watch import Finding

    watch.findings[1] = Finding(1, "tau2", 0.1, 0.015, 1e-9, 60.0, 55.0)
    message = m.ServiceDiagnostics.decode(watch.evaluate_and_encode() or b"")
    assert message.state == "dependence"
    assert message.finding is not None and message.finding.joint == 2
    assert message.command == "teleop-force residual RECORDING --model /abs/model.json"


def test_the_thread_publishes_about_once_per_period() -> None:
    got: list[bytes] = []
    watch = ResidualWatch(3, WatchConfig(period_s=0.05))
    js = m.pack_joint_state(0, T0_NS, [0.0] * 3, [0.0] * 3, [0.0] * 3)
    est = m.pack_force_estimate(0, T0_NS, 0, 3, [0.0] * 15, 7)
    watch.append(js, est)
    watch.start(got.append)
    deadline = time.perf_counter() + 5.0
    while len(got) < 3 and time.perf_counter() < deadline:
        time.sleep(0.02)
    watch.stop()
    assert len(got) >= 3 and watch.errors == 0, watch.last_error
    report = m.ServiceDiagnostics.decode(got[-1])
    assert report.device == "slave"
    # what the service's ROS 2 node publishes of it (seq: the attachment's, not in the CDR)
    payload = codec.encode_service_diagnostics(report)
    assert codec.decode_service_diagnostics(payload, report.seq) == report


def test_the_planted_effect_is_10_percent_of_the_joints_rms_torque_on_its_history() -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 0.5, (2000, 3))
    qd = rng.normal(0.0, 0.3, (2000, 3))
    tau = rng.normal(0.0, 0.1, (2000, 3))
    rms = np.sqrt(np.mean(tau * tau, axis=0))
    for name in ("load-friction", "position-friction", "drifting-friction", "cogging"):
        effect = calibrated_effect(EffectSwitch(name, scale=0.1), 60.0, rms, q, qd, tau)
        torque = effect.torque(np.full(2000, 60.0), q, qd, tau)[:, effect.joint]
        assert np.sqrt(np.mean(torque**2)) == pytest.approx(0.1 * rms[effect.joint], rel=1e-9)


def test_a_watch_with_its_own_estimator_tests_that_not_the_published_one() -> None:
    # the published estimates here claim 100 N everywhere (contact: no free row at all); the
    # watch's own estimator of the model, fed the joint states, finds the free motion
    from teleop_force.bench.data import palpation_arrays
    from teleop_force.identification.dynamic_model import DynamicModel
    from teleop_force.models import DEFAULT_MODEL_PATH
    from teleop_force.service.watch_residual import WatchResidual

    data = palpation_arrays(4.0, seed=2)
    config = WatchConfig(warmup_s=0.0, settle_s=0.0)
    junk = [100.0] * 3 + [0.0] * 12
    watches = {
        "published": ResidualWatch(3, config),
        "own": ResidualWatch(
            3, config, residual=WatchResidual(DynamicModel.load(DEFAULT_MODEL_PATH))
        ),
    }
    free = {}
    for name, watch in watches.items():
        for k in range(data["t_s"].size):
            stamp = T0_NS + k * 1_000_000
            q, tau = data["q_rad"][k].tolist(), data["tau_nm"][k].tolist()
            watch.append(
                m.pack_joint_state(k, stamp, q, [0.0] * 3, tau),
                m.pack_force_estimate(k, stamp, k, 3, junk, 7),
            )
        rows = watch._ingest()
        free[name] = 0 if rows is None else int(np.count_nonzero(rows.free))
    assert free["published"] == 0
    assert free["own"] > 20
