"""The force service's stream clock: when a joint-state stream (re)starts, and its time base."""

from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.service.stream_clock import MAX_STREAM_PAUSE_NS, StreamClock

T0 = 1_700_000_000_000_000_000

#: One step of a stream: a sample (stamp increment, seq restarted) or a reset (None).
steps = st.lists(
    st.one_of(
        st.none(),
        st.tuples(
            st.one_of(
                st.integers(-2_000_000, 2_000_000),
                st.sampled_from([0, MAX_STREAM_PAUSE_NS, MAX_STREAM_PAUSE_NS + 1]),
                st.integers(1_000, 3 * MAX_STREAM_PAUSE_NS),
            ),
            st.booleans(),
        ),
    ),
    max_size=60,
)


def play(clock: StreamClock, plan, offset: int = 0) -> list[tuple[bool, float]]:
    """Run ``plan`` from stamp ``T0 + offset``; return (stream began, t_s) per sample."""
    t_ns = T0 + offset
    out = []
    for step in plan:
        if step is None:
            clock.reset()
            continue
        dt, seq_restarted = step
        t_ns += dt
        out.append((clock.advance(t_ns, seq_restarted), clock.t_s))
    return out


def test_a_regular_stream_counts_time_from_its_first_sample():
    clock = StreamClock()
    assert clock.advance(T0, False) and clock.t_s == 0.0
    for k in range(1, 1000):
        assert not clock.advance(T0 + k * 1_000_000, False)
        assert clock.t_s == (k * 1_000_000) * 1e-9
    assert clock.restarts == 0 and clock.t0_ns == T0 and clock.last_t_ns == T0 + 999_000_000


def test_each_restart_rule():
    clock = StreamClock()
    clock.advance(T0, False)
    assert clock.advance(T0 + 1_000_000, True)  # the sequence restarted
    assert clock.advance(T0 + 1_000_000, False)  # the stamp did not increase
    assert clock.advance(T0 + 500_000, False)  # the stamp went backwards
    assert not clock.advance(T0 + 500_000 + MAX_STREAM_PAUSE_NS, False)  # a pause, at the limit
    assert clock.advance(T0 + 500_001 + 2 * MAX_STREAM_PAUSE_NS, False)  # beyond it
    assert clock.restarts == 4 and clock.t_s == 0.0
    clock.reset()
    assert clock.advance(T0 + 2 * 10**9, False)  # after a reset: a new stream, not a restart
    assert clock.restarts == 4


@settings(max_examples=300, deadline=None)
@given(steps)
def test_streams_begin_exactly_by_the_rule_and_time_counts_from_their_start(plan):
    clock = StreamClock()
    t_ns, t0, last, reset, begun, counted = T0, None, None, True, 0, 0
    for step in plan:
        if step is None:
            clock.reset()
            reset = True
            continue
        dt, seq_restarted = step
        t_ns += dt
        expected = reset or seq_restarted or t_ns <= last or t_ns - last > MAX_STREAM_PAUSE_NS
        began = clock.advance(t_ns, seq_restarted)
        assert began == expected
        if began:
            begun += 1
            counted += 0 if reset else 1
            t0 = t_ns
        reset, last = False, t_ns
        assert clock.t_s == (t_ns - t0) * 1e-9
        assert clock.t_s == 0.0 if began else clock.t_s > 0.0
    assert clock.restarts == counted <= begun


@settings(max_examples=200, deadline=None)
@given(steps, st.integers(-(10**18), 10**18))
def test_a_stream_shifted_in_time_gives_the_same_floats(plan, offset):
    assert play(StreamClock(), plan) == play(StreamClock(), plan, offset)
