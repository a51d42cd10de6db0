import math

from web.stats import RESTART_GAP, StreamStats


def test_counts_gaps_restarts_and_malformed():
    s = StreamStats()
    for seq in (0, 1, 2, 5, 6):  # 3 and 4 lost
        s.record(seq, t_ns=0, arrival_s=1.0, now_ns=0)
    s.record(2, t_ns=0, arrival_s=1.0, now_ns=0)  # backwards: a restart
    s.record(2 + RESTART_GAP + 5, t_ns=0, arrival_s=1.0, now_ns=0)  # huge jump: a restart
    s.record_malformed()
    snap = s.snapshot(now_s=1.0)
    assert (snap.received, snap.lost, snap.restarts, snap.malformed) == (7, 2, 2, 1)


def test_wraparound_is_not_a_loss():
    s = StreamStats()
    s.record(2**32 - 1, 0, 0.0, 0)
    s.record(0, 0, 0.0, 0)
    assert s.snapshot(0.0).lost == 0 and s.snapshot(0.0).restarts == 0


def test_rate_latency_and_age_over_the_window():
    s = StreamStats()
    for k in range(2000):  # 2 s at 1 kHz, 3 ms latency
        t = k * 1e-3
        s.record(k, t_ns=int(t * 1e9), arrival_s=t, now_ns=int(t * 1e9) + 3_000_000)
    snap = s.snapshot(now_s=1.9995)
    assert 990 <= snap.rate_hz <= 1010
    assert math.isclose(snap.latency_ms_mean, 3.0, rel_tol=1e-6)
    assert math.isclose(snap.latency_ms_max, 3.0, rel_tol=1e-6)
    assert math.isclose(snap.age_s, 0.0005, abs_tol=1e-9)
    idle = s.snapshot(now_s=10.0)
    assert idle.rate_hz == 0 and math.isnan(idle.latency_ms_mean)


def test_nothing_received():
    snap = StreamStats().snapshot(5.0)
    assert snap.received == 0 and math.isinf(snap.age_s) and snap.rate_hz == 0
