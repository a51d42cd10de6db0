"""Run-time controls of the force service (model load, start / stop recording) over real Zenoh.

The service runs on one loopback session; the test talks to it from a second session connected
over TCP, through the dashboard's own client (:class:`web.control.ServiceClient`) and with raw
gets for the malformed requests a dashboard would never send.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.coulomb_viscous import CoulombViscous
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import topics
from teleop_force.service.controls import PROJECT_ROOT, model_folders, record_folders
from teleop_force.service.force_service import ForceService, ServiceConfig
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from tests.ros2_traffic import Collector, JointStatePublisher
from web.control import ServiceClient

DEVICE = "ctl_test"


def joint_states(n: int, seq0: int = 0, t0_ns: int = 1_700_000_000_000_000_000) -> list:
    t = (seq0 + np.arange(n)) * 1e-3
    q = np.column_stack(
        [0.2 * np.sin(2 * t), 0.8 + 0.3 * np.sin(3 * t), 0.3 + 0.4 * np.cos(1.5 * t)]
    )
    tau = np.column_stack(
        [0.02 * np.sin(5 * t), 0.15 + 0.02 * np.cos(t), 0.05 + 0.01 * np.sin(7 * t)]
    )
    return [
        m.JointState(seq0 + k, t0_ns + (seq0 + k) * 1_000_000, q[k], np.zeros(3), tau[k])
        for k in range(n)
    ]


def wait_until(predicate, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


@pytest.fixture
def tree(tmp_path):
    """Allowed model and record folders, and an outside folder with a valid model in it."""
    models, records, outside = tmp_path / "models", tmp_path / "records", tmp_path / "outside"
    for folder in (models, records, outside):
        folder.mkdir()
    data = json.loads(DEFAULT_MODEL_PATH.read_text())
    fallback = data["friction"]["fallback"]  # the shipped model's WN: double its fallback
    fallback["parameters"] = [2.0 * x for x in fallback["parameters"]]
    (models / "doubled.json").write_text(json.dumps(data))
    (outside / "doubled.json").write_text(json.dumps(data))
    two = DynamicModel(
        "none", 2, FilterConfig(), None, np.zeros(0), np.zeros(0),
        CoulombViscous(2, np.zeros(4)), np.zeros(2),
    )  # fmt: skip
    two.save(models / "two_joints.json")
    (models / "garbage.json").write_text('{"format": "teleop-force-model", "version": 1}')
    (models / "not_json.json").write_text("{")
    (models / "model.txt").write_text(json.dumps(data))
    (models / "folder.json").mkdir()
    (models / "escape.json").symlink_to(outside / "doubled.json")
    (models / "link_dir").symlink_to(outside)
    (records / "exists.mcap").write_bytes(b"")
    (records / "dangling.mcap").symlink_to(outside / "target.mcap")
    (records / "out").symlink_to(outside)
    return {"models": models, "records": records, "outside": outside}


@pytest.fixture
def system(tree, zenoh_pair):
    """The service on its own session, and a client session connected over loopback TCP."""
    service_session, client_session = zenoh_pair.listener, zenoh_pair.connector
    config = ServiceConfig(
        device=DEVICE, models_dirs=(tree["models"],), record_dirs=(tree["records"],)
    )
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    service = ForceService(service_session, model, config, model_path=DEFAULT_MODEL_PATH).start()
    client = ServiceClient(client_session, DEVICE, timeout_s=5.0)
    collector = Collector(client_session, DEVICE, topics.ESTIMATED_CF)
    got = collector.messages
    pub = JointStatePublisher(client_session, DEVICE)
    wait_until(lambda: client.fetch_stats(timeout_s=1.0).ok, 20.0)
    wait_until(lambda: pub.publisher.zenoh_publisher.matching_status.matching, 10.0)
    time.sleep(0.1)
    try:
        yield {"service": service, "client": client, "session": client_session, "got": got,
               "pub": pub, "tree": tree}  # fmt: skip
    finally:
        collector.close()
        pub.close()
        service.close()


def stats(system) -> dict:
    reply = system["client"].fetch_stats()
    assert reply.ok, reply.text
    return reply.data


def test_keys_name_the_control_queryable():
    assert keys.service_control("slave") == "omni/slave/service/control"
    parsed = keys.parse(keys.service_control("slave"))
    assert (parsed.device, parsed.kind) == ("slave", keys.SERVICE_CONTROL)
    assert keys.parse(keys.service_adapt("slave")).kind == keys.SERVICE_ADAPT


def test_default_folders_are_the_projects():
    assert model_folders().folders == (
        (PROJECT_ROOT / "recordings").resolve(),
        DEFAULT_MODEL_PATH.parent.resolve(),
    )
    assert record_folders().folders == ((PROJECT_ROOT / "recordings").resolve(),)


@pytest.mark.zenoh
def test_a_model_is_loaded_between_samples_and_reported(system):
    client, got, pub, tree = system["client"], system["got"], system["pub"], system["tree"]
    before = joint_states(300)
    after = joint_states(300, seq0=300)
    for js in before:
        pub.send(js)
    wait_until(lambda: len(got) == 300)
    target = tree["models"] / "doubled.json"
    reply = client.request_model_load(target)
    assert reply.ok, reply.text
    assert reply.data == {"ok": True, "path": str(target.resolve()), "friction": "wn"}
    for js in after:
        pub.send(js)
    wait_until(lambda: len(got) == 600)
    st = stats(system)
    assert st["model"]["path"] == str(target.resolve()) and st["model"]["loads"] == 1
    assert st["joint_states"]["lost"] == 0 and st["estimates"]["errors"] == 0
    assert st["estimates"]["published"] == 600
    assert [e.source_seq for e in got] == list(range(600))
    # From the first sample after the swap, exactly the new model on a fresh stream.
    fresh = ForceEstimator(DynamicModel.load(target))
    t0 = after[0].t_ns
    for js, estimate in zip(after, got[300:], strict=True):
        expected = fresh.update((js.t_ns - t0) * 1e-9, np.array(js.q_rad), np.array(js.effort_nm))
        assert estimate.tau_ext_nm == tuple(expected.tau_external_nm)
    served = client.fetch_model()
    assert served.ok and served.data == DynamicModel.load(target).to_dict()


@pytest.mark.zenoh
def test_loading_while_streaming_loses_nothing(system):
    client, got, pub, tree = system["client"], system["got"], system["pub"], system["tree"]
    stream = joint_states(1500)
    done = threading.Event()

    def publish():
        for k, js in enumerate(stream):
            pub.send(js)
            if k % 4 == 0:
                time.sleep(0.001)
        done.set()

    thread = threading.Thread(target=publish)
    thread.start()
    targets = [tree["models"] / "doubled.json", DEFAULT_MODEL_PATH] * 3
    replies = [client.request_model_load(path) for path in targets]
    thread.join()
    wait_until(lambda: len(got) == len(stream), 20.0)
    assert all(r.ok for r in replies), [r.text for r in replies]
    st = stats(system)
    assert st["model"]["loads"] == len(targets)
    assert st["joint_states"]["lost"] == 0 and st["estimates"]["errors"] == 0
    assert st["estimates"]["published"] == len(stream)
    assert [e.source_seq for e in got] == list(range(len(stream)))


def refused_loads(tree) -> list[object]:
    models, outside = tree["models"], tree["outside"]
    return [
        "/etc/passwd",
        str(outside / "doubled.json"),                      # a valid model, outside
        f"{models}/../outside/doubled.json",                # .. out of the folder
        str(models / "escape.json"),                        # symlink pointing outside
        str(models / "link_dir" / "doubled.json"),          # through a symlinked folder
        "models/doubled.json",                              # relative
        str(models / "model.txt"),                          # wrong suffix
        str(models / "folder.json"),                        # a directory
        str(models / "missing.json"),
        str(models / "two_joints.json"),                    # wrong joint count
        str(models / "garbage.json"),                       # not a complete model
        str(models / "not_json.json"),
        str(models) + "/doubled.json\x00.txt",
        "",
        "/" + "a" * 5000 + ".json",
        42,
        None,
        ["/etc/passwd"],
    ]  # fmt: skip


@pytest.mark.zenoh
def test_loads_outside_the_allowed_folders_or_of_bad_files_are_refused(system):
    client, session, tree = system["client"], system["session"], system["tree"]
    paths = refused_loads(tree)
    for path in paths:
        reply = client.query(keys.service_model(DEVICE), {"load": path})
        assert not reply.ok, (path, reply.data)
        assert reply.data["ok"] is False and reply.data["error"], path
    bad_payloads = [b"not json", b"[1, 2]", b'"load"', b"\xff\xfe", b"{" * 100_000]
    for payload in bad_payloads:
        replies = list(session.get(keys.service_model(DEVICE), payload=payload, timeout=5.0))
        assert json.loads(replies[0].ok.payload.to_string())["ok"] is False
    wrong_keys = client.query(keys.service_model(DEVICE), {"load": "/x.json", "also": 1})
    assert not wrong_keys.ok
    st = stats(system)
    assert st["model"]["path"] == str(DEFAULT_MODEL_PATH) and st["model"]["loads"] == 0
    assert st["controls"]["refused"] == len(paths) + len(bad_payloads) + 1
    assert st["malformed"]["by_key"] == {keys.service_model(DEVICE): len(bad_payloads)}
    # The service still runs its model and estimates.
    for js in joint_states(50):
        system["pub"].send(js)
    wait_until(lambda: len(system["got"]) == 50)
    assert client.fetch_model().data == DynamicModel.load(DEFAULT_MODEL_PATH).to_dict()


@pytest.mark.zenoh
def test_recordings_outside_the_allowed_folders_are_refused(system):
    client, tree = system["client"], system["tree"]
    records, outside = tree["records"], tree["outside"]
    refused = [
        outside / "x.mcap",
        Path(f"{records}/../outside/x.mcap"),
        records / "out" / "x.mcap",       # through a symlinked folder
        records / "exists.mcap",          # never overwritten
        records / "dangling.mcap",        # a symlink, even a dangling one
        records / "missing" / "x.mcap",   # no such folder
        records / "x.txt",
        records / ".mcap" / "..",
        Path("/proc/self/x.mcap"),
        Path(str(records / "x") + "\x00.mcap"),
    ]  # fmt: skip
    for path in refused:
        reply = client.set_recording(True, path)
        assert not reply.ok, (path, reply.data)
    raw = [{"record": "start", "path": "x.mcap"}, {"record": "start"}, {"record": "pause"},
           {"record": "start", "path": 5}, {}, {"record": "stop", "path": "/x.mcap"}]  # fmt: skip
    for payload in raw:
        assert not client.query(keys.service_control(DEVICE), payload).ok, payload
    assert not (outside / "x.mcap").exists() and not (outside / "target.mcap").exists()
    assert (records / "exists.mcap").read_bytes() == b""
    st = stats(system)
    assert st["recording"] is None
    assert st["controls"]["refused"] == len(refused) + len(raw)
    assert sorted(os.listdir(records)) == ["dangling.mcap", "exists.mcap", "out"]


def test_service_cli_flags_reach_the_config():
    from teleop_force.service.force_service import build_parser

    args = build_parser().parse_args(
        [
            "--models-dir",
            "/a",
            "--models-dir",
            "/b",
            "--record-dir",
            "/c",
            "--record-flush-s",
            "0.1",
        ]
    )
    assert args.models_dir == [Path("/a"), Path("/b")] and args.record_dir == [Path("/c")]
    assert args.record_flush_s == 0.1
