import json
import sys
import time
from pathlib import Path

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.transport import keys
from teleop_force.transport.session import ZenohOptions
from web.control import (
    ReplayProcess,
    ServiceClient,
    adaptation_request,
    control_key,
    load_model_request,
    record_request,
    recording_name,
    replay_command,
    stats_adaptation,
    stats_model_path,
    stats_recording,
    zenoh_cli_args,
)


def test_request_keys_and_payloads():
    assert control_key("slave") == "omni/slave/service/control"
    assert load_model_request("slave", Path("/x/m.json")) == (
        "omni/slave/service/model",
        {"load": "/x/m.json"},
    )
    assert record_request("s", True, Path("/r/a.mcap")) == (
        "omni/s/service/control",
        {"record": "start", "path": "/r/a.mcap"},
    )
    assert record_request("s", False) == ("omni/s/service/control", {"record": "stop"})
    assert adaptation_request("s", True) == ("omni/s/service/adapt", "on")
    assert adaptation_request("s", False) == ("omni/s/service/adapt", "off")
    with pytest.raises(ConfigurationError):
        record_request("s", True)
    with pytest.raises(ConfigurationError):
        control_key("a/b")


def test_reading_the_service_statistics():
    stats = {
        "model": {"path": "/m/../m/a.json"},
        "adaptation": {"enabled": False, "note": "needs a WN"},
        "recording": {"path": "/r/x.mcap", "messages": 12},
    }
    assert stats_model_path(stats) == Path("/m/a.json")
    assert stats_adaptation(stats) == (False, "needs a WN")
    assert stats_recording(stats) == "recording x.mcap (12 messages)"
    assert stats_recording({"recording": None}) == "not recording"
    assert stats_model_path({}) is None and stats_model_path(None) is None
    assert stats_adaptation({"adaptation": {}}) == (None, "") and stats_recording(None) == "unknown"


def test_recording_names_are_plain_file_names():
    assert recording_name("run1") == "run1.mcap"
    assert recording_name("run1.mcap") == "run1.mcap"
    assert recording_name("", now=0).startswith("session-")
    for bad in ("../x", "a/b", ".hidden", "x y", "a\x00"):
        with pytest.raises(ConfigurationError):
            recording_name(bad)


def test_replay_command_and_zenoh_flags():
    opts = ZenohOptions(mode="peer", connect=("tcp/127.0.0.1:7447",), multicast_scouting=False)
    args = zenoh_cli_args(opts)
    assert args == ["--mode", "peer", "--connect", "tcp/127.0.0.1:7447", "--no-multicast"]
    cmd = replay_command(Path("/r/a.mcap"), 2.0, args, program=["tf"])
    assert cmd == ["tf", "replay", "/r/a.mcap", "--speed", "2", *args]
    with pytest.raises(ConfigurationError):
        replay_command(Path("/r/a.mcap"), 0.0, [], program=["tf"])
    assert zenoh_cli_args(ZenohOptions()) == []


def test_replay_process_start_status_stop():
    replay = ReplayProcess()
    assert replay.status() == "idle" and replay.stop() == "no replay running"
    line = replay.start([sys.executable, "-c", "import time; time.sleep(30)"], "a.mcap at x1")
    assert "pid" in line and replay.status().startswith("running")
    assert "stopped" in replay.stop()
    replay.start([sys.executable, "-c", "import sys; sys.exit('bad recording')"], "b.mcap")
    deadline = time.monotonic() + 10
    while replay.status().startswith("running") and time.monotonic() < deadline:
        time.sleep(0.05)
    assert replay.status() == "finished: b.mcap, exit 1: bad recording"
    assert "cannot start" in replay.start(["/nonexistent/teleop-force"], "c")


@pytest.fixture
def session(zenoh_session):
    """The fake service's and the client's loopback peer (tests/conftest.py)."""
    return zenoh_session


@pytest.mark.zenoh
def test_service_client_round_trips_over_zenoh(session):
    seen = []

    def answer(query):
        payload = None if query.payload is None else json.loads(query.payload.to_string())
        seen.append((str(query.key_expr), payload))
        if payload and payload.get("load", "").endswith("bad.json"):
            query.reply(query.key_expr, json.dumps({"ok": False, "error": "not a model"}))
        else:
            query.reply(query.key_expr, json.dumps({"ok": True, "friction": {"kind": "cv"}}))

    queryables = [
        session.declare_queryable(k, answer) for k in (keys.service_model("s"), control_key("s"))
    ]
    try:
        client = ServiceClient(session, "s", timeout_s=2.0)
        assert client.request_model_load(Path("/m/good.json")).ok
        failed = client.request_model_load(Path("/m/bad.json"))
        assert not failed.ok and failed.text == "not a model"
        fetched = client.fetch_model()
        assert fetched.ok and fetched.data["friction"]["kind"] == "cv"
        got = []
        sub = session.declare_subscriber(
            keys.service_adapt("s"), lambda x: got.append(x.payload.to_string())
        )
        assert client.set_adaptation(True).ok
        assert client.set_adaptation(False).ok
        deadline = time.monotonic() + 5
        while len(got) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        sub.undeclare()
        assert got == ["on", "off"]
        assert client.set_recording(True, Path("/r/x.mcap")).ok
        missing = client.fetch_stats(timeout_s=0.3)
        assert not missing.ok and "no reply" in missing.text
    finally:
        for q in queryables:
            q.undeclare()
    assert seen == [
        ("omni/s/service/model", {"load": "/m/good.json"}),
        ("omni/s/service/model", {"load": "/m/bad.json"}),
        ("omni/s/service/model", None),
        ("omni/s/service/control", {"record": "start", "path": "/r/x.mcap"}),
    ]
