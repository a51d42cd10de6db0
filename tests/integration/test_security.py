"""Security defaults: loopback-only listeners, Zenoh TLS (and mTLS), access control.

The certificates are made by the test with the ``openssl`` command (a throw-away CA and one
certificate for 127.0.0.1 / localhost, valid for a day); without ``openssl`` the TLS tests are
skipped. The service-side refusal of files outside the allowed folders is in
``tests/service/test_service_controls.py``, the dashboard side in
``tests/web/test_web_allowlist.py``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from ros2_traffic import Collector, JointStatePublisher
from teleop_helpers import (
    STARTUP_TIMEOUT_S,
    python_module,
    spawn,
    stop,
    tcp_port_open,
    wait_for,
)

from teleop_force.errors import TransportError
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import topics
from teleop_force.service.force_service import ForceService, ServiceConfig
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import query_json
from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)

pytestmark = pytest.mark.zenoh
ROOT = Path(__file__).resolve().parents[2]
OPENSSL = shutil.which("openssl")
needs_openssl = pytest.mark.skipif(
    OPENSSL is None,
    reason="the openssl command is not installed (apt-get install openssl): no certificate "
    "can be made for the TLS test",
)


# --------------------------------------------------------------------------- sockets


def _hex_address(text: str) -> str:
    """/proc/net/tcp* local address -> dotted IPv4 or compressed IPv6."""
    address, port = text.split(":")
    raw = bytes.fromhex(address)
    if len(raw) == 4:
        host = socket.inet_ntop(socket.AF_INET, raw[::-1])
    else:  # four little-endian 32-bit words
        words = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
        host = socket.inet_ntop(socket.AF_INET6, words)
    return f"{host}:{int(port, 16)}"


def socket_inodes(pid: int) -> set[str]:
    inodes = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    try:
        for fd in fd_dir.iterdir():
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            match = re.fullmatch(r"socket:\[(\d+)\]", target)
            if match:
                inodes.add(match.group(1))
    except OSError:
        pass
    return inodes


def listening_sockets(pids: list[int]) -> list[tuple[int, str, str]]:
    """``(pid, protocol, local address)`` of every TCP listener and bound UDP socket."""
    owner = {inode: pid for pid in pids for inode in socket_inodes(pid)}
    found = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        try:
            lines = Path(f"/proc/net/{proto}").read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            local, state, inode = fields[1], fields[3], fields[9]
            listening = state == "0A" if proto.startswith("tcp") else True
            if listening and inode in owner:
                found.append((owner[inode], proto, _hex_address(local)))
    return found


def is_loopback(address: str) -> bool:
    host = address.rsplit(":", 1)[0]
    return host.startswith("127.") or host in ("::1", "::ffff:127.0.0.1")


def descendants(pid: int) -> list[int]:
    """``pid`` and every process below it."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo += children.get(p, [])
    return out


def test_the_socket_check_sees_a_non_loopback_listener():
    """The checker itself: a session asked to listen on 0.0.0.0 is reported."""
    session = open_session(
        ZenohOptions(mode="peer", listen=("tcp/0.0.0.0:0",), multicast_scouting=False)
    )
    try:
        found = listening_sockets([os.getpid()])
    finally:
        session.close()
    assert any(not is_loopback(address) for _, _, address in found), found


def test_service_and_dashboard_listen_on_loopback_only(tmp_path):
    """The default flags of ``python -m teleop_force.service.force_service`` and ``python -m
    web``."""
    endpoint = listen_endpoint(free_tcp_port())
    session = open_session(ZenohOptions(mode="peer", listen=(endpoint,), multicast_scouting=False))
    tokens: set[str] = set()
    sub = session.liveliness().declare_subscriber(
        keys.alive_any(), lambda s: tokens.add(str(s.key_expr)), history=True
    )
    log = tmp_path / "processes.log"
    port = free_tcp_port()
    processes = [
        spawn(
            python_module(
                "teleop_force.service.force_service", "--device", "sec", "--connect", endpoint
            ),
            log,
        ),
        spawn(
            python_module("web", "--device", "sec", "--port", str(port), "--connect", endpoint), log
        ),
    ]
    try:
        wait_for(lambda: keys.alive("sec", "service") in tokens, STARTUP_TIMEOUT_S, "service")
        wait_for(lambda: tcp_port_open(port), STARTUP_TIMEOUT_S, f"dashboard\n{_tail(log)}", 0.2)
        time.sleep(0.5)
        pids = [pid for p in processes for pid in descendants(p.pid)]
        found = listening_sockets(pids)
    finally:
        for p in processes:
            stop(p)
        sub.undeclare()
        session.close()
    assert any(address.endswith(f":{port}") for _, _, address in found), found  # dashboard
    assert sum(proto.startswith("tcp") for _, proto, _ in found) >= 2, found  # + zenoh
    exposed = [s for s in found if not is_loopback(s[2])]
    assert not exposed, f"listening beyond loopback: {exposed}"


@pytest.mark.slow  # the whole demo (4 processes) starts in ~20-60 s on a shared machine
def test_demo_listens_on_loopback_only(tmp_path):
    port, zenoh_port = free_tcp_port(), free_tcp_port()
    demo = subprocess.Popen(
        python_module("teleop_force.cli.main", "demo", "--port", str(port), "--record-dir",
                      str(tmp_path), "--zenoh-port", str(zenoh_port)),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        lines = []
        deadline = time.monotonic() + STARTUP_TIMEOUT_S * 3
        while time.monotonic() < deadline:
            line = demo.stdout.readline()
            lines.append(line)
            if "all processes up" in line or not line:
                break
        assert any("all processes up" in x for x in lines), "".join(lines)
        wait_for(lambda: tcp_port_open(port), STARTUP_TIMEOUT_S, "the dashboard", 0.2)
        time.sleep(1.0)
        pids = descendants(demo.pid)
        found = listening_sockets(pids)
    finally:
        stop(demo, timeout_s=30.0)
    assert len(pids) >= 6, pids  # supervisor, router, service, slave, master, dashboard
    assert any(address.endswith(f":{port}") for _, _, address in found), found
    assert any(address.endswith(f":{zenoh_port}") for _, _, address in found), found  # router
    exposed = [s for s in found if not is_loopback(s[2])]
    assert not exposed, f"listening beyond loopback: {exposed}"
    print(f"\ndemo listeners ({len(found)}): {sorted({a for _, _, a in found})}")


def test_a_config_file_without_listen_endpoints_still_listens_on_loopback_only(tmp_path):
    config = tmp_path / "tls-only.json5"
    config.write_text("{ scouting: { multicast: { enabled: false } } }\n")
    session = open_session(ZenohOptions(config_path=config))
    try:
        found = listening_sockets([os.getpid()])
    finally:
        session.close()
    exposed = [s for s in found if not is_loopback(s[2])]
    assert not exposed, f"listening beyond loopback: {exposed}"


def _tail(path: Path) -> str:
    try:
        return path.read_text(errors="replace")[-2000:]
    except OSError:
        return ""


# --------------------------------------------------------------------------- TLS


@pytest.fixture(scope="module")
def certificates(tmp_path_factory) -> dict[str, Path]:
    """A CA, and a certificate for 127.0.0.1 / localhost (server and client use) signed by it."""
    if OPENSSL is None:
        pytest.skip("openssl not installed")
    d = tmp_path_factory.mktemp("tls")
    ext = d / "ext.cnf"
    ext.write_text(
        "subjectAltName=IP:127.0.0.1,DNS:localhost\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth,clientAuth\n"
    )

    def run(*args: str) -> None:
        subprocess.run([OPENSSL, *args], cwd=d, check=True, capture_output=True, timeout=60)

    for name in ("ca", "other-ca"):
        subject = f"/CN=teleop-force test {name}"
        run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}-key.pem",
            "-out", f"{name}.pem", "-days", "1", "-subj", subject)  # fmt: skip
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "peer-key.pem", "-out", "peer.csr",
        "-subj", "/CN=localhost")  # fmt: skip
    run("x509", "-req", "-in", "peer.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
        "-CAcreateserial", "-out", "peer.pem", "-days", "1", "-extfile", "ext.cnf")  # fmt: skip
    return {name: d / f"{name}.pem" for name in ("ca", "other-ca", "peer", "peer-key")}


def tls_config(path: Path, certs: dict[str, Path], *, ca: str = "ca", mtls: bool = False,
               client_cert: bool = True) -> Path:  # fmt: skip
    """A Zenoh config file with the keys documented in ``teleop_force/transport/session.py``."""
    tls = {
        "root_ca_certificate": str(certs[ca]),
        "listen_private_key": str(certs["peer-key"]),
        "listen_certificate": str(certs["peer"]),
        "enable_mtls": mtls,
        "verify_name_on_connect": True,
    }
    if client_cert:
        tls["connect_private_key"] = str(certs["peer-key"])
        tls["connect_certificate"] = str(certs["peer"])
    config = {"transport": {"link": {"tls": tls}}, "scouting": {"multicast": {"enabled": False}}}
    path.write_text(json.dumps(config, indent=1))
    return path


def _listener(endpoint: str, config: Path) -> zenoh.Session:
    return open_session(ZenohOptions(mode="peer", listen=(endpoint,), config_path=config))


def _client(endpoint: str, config: Path | None) -> zenoh.Session:
    return open_session(
        ZenohOptions(
            mode="client", connect=(endpoint,), config_path=config, multicast_scouting=False
        )
    )


@needs_openssl
@pytest.mark.parametrize("mtls", [False, True], ids=["tls", "mtls"])
def test_service_over_tls_and_plain_or_untrusted_clients_are_refused(tmp_path, certificates, mtls):
    port = free_tcp_port()
    endpoint = f"tls/127.0.0.1:{port}"
    server = _listener(endpoint, tls_config(tmp_path / "server.json5", certificates, mtls=mtls))
    device = "tls_slave"
    service = ForceService(
        server, DynamicModel.load(DEFAULT_MODEL_PATH), ServiceConfig(device=device)
    ).start()
    client = None
    try:
        # With mTLS both sides set enable_mtls (the client then presents its certificate).
        client = _client(endpoint, tls_config(tmp_path / "client.json5", certificates, mtls=mtls))
        estimates = Collector(client, device, topics.ESTIMATED_CF)
        driver = JointStatePublisher(client, device)
        try:
            matched = driver.publisher.zenoh_publisher
            wait_for(lambda: matched.matching_status.matching, 10.0, "the service over TLS")
            time.sleep(0.1)
            for k in range(100):
                js = m.JointState(k, 1_700_000_000_000_000_000 + k * 1_000_000, (0.1, 0.8, 0.3),
                                  (0.0,) * 3, (0.0, 0.1, 0.05))  # fmt: skip
                driver.send(js)
            wait_for(lambda: len(estimates) == 100, 10.0, "100 estimates over TLS")
            stats = query_json(client, keys.service_stats(device), 5.0)
        finally:
            estimates.close()
            driver.close()
        got = estimates.messages
        assert stats["joint_states"]["received"] == 100 and stats["joint_states"]["lost"] == 0
        assert [e.source_seq for e in got] == list(range(100))
        # A plain TCP client gets nowhere: the port speaks TLS only.
        with pytest.raises(TransportError):
            _client(f"tcp/127.0.0.1:{port}", None)
        # Nor does a TLS client that trusts another CA (it cannot verify the server).
        with pytest.raises(TransportError):
            _client(endpoint, tls_config(tmp_path / "other.json5", certificates, ca="other-ca"))
        if mtls:  # and with mTLS, a client without a certificate is refused
            anonymous = tls_config(tmp_path / "anon.json5", certificates, client_cert=False)
            with pytest.raises(TransportError):
                _client(endpoint, anonymous)
    finally:
        if client is not None:
            client.close()
        service.close()
        server.close()


# --------------------------------------------------------------------------- access control


def acl_config(path: Path) -> Path:
    """Read-only for remote peers: no put on adapt, no query on control and model loads."""
    config = {
        "scouting": {"multicast": {"enabled": False}},
        "access_control": {
            "enabled": True,
            "default_permission": "allow",
            "rules": [
                {
                    "id": "no-remote-control",
                    "permission": "deny",
                    "flows": ["ingress"],
                    "messages": ["put", "query"],
                    "key_exprs": [
                        "omni/*/service/adapt",
                        "omni/*/service/control",
                        "omni/*/service/model",
                    ],
                }
            ],
            "subjects": [{"id": "everyone-on-loopback", "interfaces": ["lo"]}],
            "policies": [{"rules": ["no-remote-control"], "subjects": ["everyone-on-loopback"]}],
        },
    }
    path.write_text(json.dumps(config, indent=1))
    return path


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the 'lo' interface name")
def test_access_control_makes_the_service_read_only_for_remote_peers(tmp_path):
    port = free_tcp_port()
    endpoint = listen_endpoint(port)
    server = open_session(
        ZenohOptions(
            mode="peer", listen=(endpoint,), config_path=acl_config(tmp_path / "acl.json5")
        )
    )
    device = "acl_slave"
    models = tmp_path / "models"
    models.mkdir()
    service = ForceService(
        server, DynamicModel.load(DEFAULT_MODEL_PATH),
        ServiceConfig(device=device, models_dirs=(models,), record_dirs=(tmp_path,)),
    ).start()  # fmt: skip
    (models / "m.json").write_text(DEFAULT_MODEL_PATH.read_text())
    client = open_session(
        ZenohOptions(mode="peer", connect=(endpoint,), listen=(), multicast_scouting=False)
    )
    try:
        stats = None
        deadline = time.monotonic() + 10
        while stats is None and time.monotonic() < deadline:
            try:
                stats = query_json(client, keys.service_stats(device), 2.0)  # allowed
            except TransportError:
                time.sleep(0.1)
        assert stats is not None
        client.put(keys.service_adapt(device), "on")
        stop_request = json.dumps({"record": "stop"})
        load_request = json.dumps({"load": str(models / "m.json")})
        control = list(client.get(keys.service_control(device), payload=stop_request, timeout=1.5))
        load = list(client.get(keys.service_model(device), payload=load_request, timeout=1.5))
        time.sleep(0.3)
        after = query_json(client, keys.service_stats(device), 5.0)
        # The same requests from inside the service's own session are not filtered.
        local = list(server.get(keys.service_control(device), payload=stop_request, timeout=5.0))
    finally:
        client.close()
        service.close()
        server.close()
    assert control == [] and load == []  # denied: the queries never reached the service
    assert after["controls"]["requests"] == 0 and after["model"]["loads"] == 0
    assert service.adaptation_state.note or after["adaptation"]["enabled"] is False
    assert len(local) == 1 and local[0].ok is not None
