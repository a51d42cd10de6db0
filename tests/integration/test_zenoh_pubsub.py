"""Real Zenoh traffic on loopback between two peer sessions (multicast scouting off)."""

import argparse
import itertools
import json
import queue
import time

import pytest
import zenoh
from ros2_traffic import Collector, JointStatePublisher

from teleop_force.errors import ConfigurationError, TransportError
from teleop_force.ros2 import topics
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.session import (
    ZenohOptions,
    add_zenoh_arguments,
    free_tcp_port,
    listen_endpoint,
    open_session,
    options_from_args,
)

TIMEOUT_S = 10.0


def wait_for(predicate, timeout_s=TIMEOUT_S, what="condition"):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.zenoh
def test_pub_sub_joint_states_with_congestion_control_block(zenoh_pair):
    """ROS 2 JointStates (CDR + rmw_zenoh's attachment) from a reliable BLOCK publisher."""
    a, b = zenoh_pair.listener, zenoh_pair.connector
    received = Collector(b, "dev1", topics.MEASURED_JS, n_joints=3)
    driver = JointStatePublisher(a, "dev1")  # declare_data_publisher: BLOCK, reliable
    probe = m.JointState(0, time.time_ns(), (0.1, 0.2, 0.3), (0.0,) * 3, (0.0,) * 3)
    try:
        publisher = driver.publisher.zenoh_publisher
        wait_for(lambda: publisher.matching_status.matching, what="the subscriber to be matched")
        # Zenoh 1.10 may still drop what is put in the first milliseconds after the match:
        # probe (seq 0) until one message made the round trip, then nothing may be lost.
        deadline = time.monotonic() + TIMEOUT_S
        while not received.messages:
            driver.send(probe)
            time.sleep(0.02)
            assert time.monotonic() < deadline, "no probe got through"
        count = 500
        t0 = time.time_ns()
        for i in range(1, count + 1):
            js = m.JointState(i, time.time_ns(), (0.1, 0.2, 0.3), (0.0,) * 3, (0.01, 0.0, -0.01))
            driver.send(js)
        wait_for(lambda: sum(g.seq != 0 for g in received.messages) == count)
        time.sleep(0.1)  # nothing more (no duplicate) arrives
    finally:
        driver.close()
        received.close()
    got = [g for g in received.messages if g.seq != 0]  # not a late probe
    attachments = [x for x in received.attachments if x.sequence_number != 0]
    assert [g.seq for g in got] == list(range(1, count + 1))  # BLOCK + reliable: nothing lost
    assert all(g.t_ns >= t0 and g.q_rad == (0.1, 0.2, 0.3) for g in got)
    assert all(m.sequence_gap(x.seq, y.seq) == 0 for x, y in itertools.pairwise(got))
    assert {x.gid for x in attachments} == {driver.publisher.gid}
    assert all(x.source_timestamp_ns >= t0 for x in attachments)
    assert not received.malformed


@pytest.mark.zenoh
def test_liveliness_token_appears_and_disappears(zenoh_pair):
    a, b = zenoh_pair.listener, zenoh_pair.connector
    events: queue.Queue[tuple[str, str]] = queue.Queue()

    def on_change(sample):
        kind = "PUT" if sample.kind == zenoh.SampleKind.PUT else "DELETE"
        events.put((str(sample.key_expr), kind))

    sub = b.liveliness().declare_subscriber(keys.alive_any(), on_change)
    try:
        token = a.liveliness().declare_token(keys.alive("dev1", "slave"))
        assert events.get(timeout=TIMEOUT_S) == ("omni/dev1/alive/slave", "PUT")
        token.undeclare()
        assert events.get(timeout=TIMEOUT_S) == ("omni/dev1/alive/slave", "DELETE")
    finally:
        sub.undeclare()


@pytest.mark.zenoh
def test_client_without_router_raises_transport_error():
    port = free_tcp_port()  # nothing listens there
    with pytest.raises(TransportError, match="cannot open zenoh session"):
        open_session(ZenohOptions(mode="client", connect=(listen_endpoint(port),)))


@pytest.mark.zenoh
def test_invalid_endpoint_raises_transport_error():
    with pytest.raises(TransportError):
        open_session(ZenohOptions(listen=("tcp/127.0.0.1:notaport",)))


# ------------------------------------------------------------------------------ options


def parse(argv):
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    return options_from_args(parser.parse_args(argv))


def config_value(options, key):
    return json.loads(options.to_config().get_json(key))


def test_defaults_are_loopback_peer_without_multicast():
    options = parse([])
    assert options == ZenohOptions()
    assert config_value(options, "mode") == "peer"
    assert config_value(options, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert config_value(options, "scouting/multicast/enabled") is False


def test_flags_are_applied():
    options = parse(
        [
            "--mode",
            "client",
            "--connect",
            "tcp/127.0.0.1:7447,tcp/127.0.0.1:7448",
            "--connect",
            "tcp/10.0.0.2:7447",
            "--multicast",
        ]
    )
    assert options.connect == ("tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448", "tcp/10.0.0.2:7447")
    assert config_value(options, "mode") == "client"
    assert config_value(options, "connect/endpoints") == list(options.connect)
    assert config_value(options, "scouting/multicast/enabled") is True
    assert parse(["--no-multicast"]).multicast_scouting is False
    assert parse(["--listen", "tcp/0.0.0.0:7447"]).listen == ("tcp/0.0.0.0:7447",)


def test_config_file_is_the_base_and_flags_override(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text(
        '{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:7999"] },'
        " scouting: { multicast: { enabled: true } } }"
    )
    from_file = parse(["--config", str(path)])
    assert config_value(from_file, "listen/endpoints") == ["tcp/127.0.0.1:7999"]
    assert config_value(from_file, "scouting/multicast/enabled") is True
    overridden = parse(["--config", str(path), "--no-multicast", "--listen", "tcp/127.0.0.1:0"])
    assert config_value(overridden, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert config_value(overridden, "scouting/multicast/enabled") is False


def test_bad_options_raise_configuration_error(tmp_path):
    with pytest.raises(ConfigurationError):
        ZenohOptions(mode="server")  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match="tcp/HOST:PORT"):
        ZenohOptions(connect=("localhost:7447",))
    with pytest.raises(ConfigurationError, match="cannot load"):
        ZenohOptions(config_path=tmp_path / "missing.json5").to_config()
    with pytest.raises(ConfigurationError):
        listen_endpoint(70000)
