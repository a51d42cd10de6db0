import math

from web_ros2 import attachment

from web.stats import MAX_PUBLISHERS, RESTART_GAP, StreamStats

OTHER_GID = bytes(range(1, 17))


def test_counts_gaps_restarts_and_malformed():
    s = StreamStats()
    for seq in (1, 2, 3, 6, 7):  # 4 and 5 lost
        s.record(attachment(seq), arrival_s=1.0, now_ns=0)
    s.record(attachment(1), arrival_s=1.0, now_ns=0)  # backwards: a restart, same GID
    s.record(attachment(1 + RESTART_GAP + 5), arrival_s=1.0, now_ns=0)  # huge jump: a restart
    s.record_malformed()
    snap = s.snapshot(now_s=1.0)
    assert (snap.received, snap.lost, snap.restarts, snap.malformed) == (7, 2, 2, 1)


def test_each_publisher_has_its_own_sequence():
    s = StreamStats()
    for seq in (1, 2, 3):
        s.record(attachment(seq), 0.0, 0)
        s.record(attachment(seq + 100, gid=OTHER_GID), 0.0, 0)  # a second publisher appears
    s.record(attachment(5), 0.0, 0)  # 4 lost
    snap = s.snapshot(0.0)
    assert snap.lost == 1 and snap.restarts == 1


def test_the_publishers_kept_are_bounded():
    s = StreamStats()
    for k in range(MAX_PUBLISHERS + 1):
        s.record(attachment(1, gid=bytes([k]) * 16), 0.0, 0)
    s.record(attachment(2, gid=bytes([0]) * 16), 0.0, 0)  # forgotten: seen as new again
    snap = s.snapshot(0.0)
    assert snap.lost == 0 and snap.restarts == MAX_PUBLISHERS + 1


def test_rate_latency_and_age_over_the_window():
    s = StreamStats()
    for k in range(2000):  # 2 s at 1 kHz, 3 ms from the source timestamp to arrival
        t = k * 1e-3
        s.record(attachment(k + 1, int(t * 1e9)), arrival_s=t, now_ns=int(t * 1e9) + 3_000_000)
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
