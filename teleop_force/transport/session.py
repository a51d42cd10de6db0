"""Open a Zenoh session the way zenoh-python's examples do, with the project's safe defaults.

Defaults: peer mode, listening on ``tcp/127.0.0.1:0`` (loopback only, a free port chosen by
the OS), multicast scouting off. With scouting off, peers find each other only through
explicit endpoints: one process listens on a known port (``listen_endpoint(port)``) and the
others ``--connect`` to it; Zenoh's gossip then tells each peer about the others.

Every command shares the same flags (``add_zenoh_arguments``)::

    --mode peer|client|router   --connect ENDPOINT...   --listen ENDPOINT...
    --config FILE               --multicast / --no-multicast

A ``--config`` file (Zenoh JSON5) is loaded first; flags given on the command line override
it, and the project defaults apply only to what neither sets.

TLS
---
Use ``tls/`` endpoints instead of ``tcp/`` (``--listen tls/0.0.0.0:7447`` on the listening
side, ``--connect tls/robot-pc.local:7447`` on the others) and a config file giving the
certificates under ``transport/link/tls``::

    {
      transport: { link: { tls: {
        root_ca_certificate: "/etc/teleop/ca.pem",       // CA that signed the peers' certs
        listen_private_key: "/etc/teleop/server-key.pem",  // listening side
        listen_certificate: "/etc/teleop/server.pem",
        enable_mtls: true,                              // also authenticate connecting side
        connect_private_key: "/etc/teleop/client-key.pem", // connecting side (mTLS)
        connect_certificate: "/etc/teleop/client.pem",
        verify_name_on_connect: true,                   // certificate name must match host
      } } },
    }

then ``--config that-file.json5``. The same keys can be set programmatically with
``zenoh.Config.insert_json5("transport/link/tls/root_ca_certificate", '"/etc/teleop/ca.pem"')``.
The certificate of the listening side must name the host the others connect to (or use
``verify_name_on_connect: false`` on a closed network). See https://zenoh.io/docs/manual/tls/.

Zenoh's threads
---------------
Unless ``ZENOH_RUNTIME`` is set in the environment, a session runs Zenoh's receiving,
networking, accepting and application tasks on one thread and sends on another
(:data:`DEFAULT_RUNTIME`, Zenoh's own syntax). Zenoh's default spreads them over five
runtimes, so every sample received wakes two or three threads: the socket's readiness on
one, the reading task on another. Sending stays on a thread of its own because the service
publishes from its subscriber's callback: on a single thread, a publication that waits for
room in the send queue (congestion control BLOCK) would wait for the very thread it holds.
The variable is read once per process, when the first session opens (figures:
docs/architecture.md, "Zenoh's threads").
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final, Literal

import zenoh

from teleop_force.errors import ConfigurationError, TransportError

Mode = Literal["peer", "client", "router"]
MODES: Final = ("peer", "client", "router")
#: Loopback, any free port: the default listening endpoint of a peer.
DEFAULT_LISTEN: Final = ("tcp/127.0.0.1:0",)
DEFAULT_MODE: Final = "peer"
#: ``ZENOH_RUNTIME`` a session opens with unless the environment sets it: everything but
#: sending on one thread, sending on another.
DEFAULT_RUNTIME: Final = (
    "(rx: (worker_threads: 1), net: (handover: rx), acc: (handover: rx), app: (handover: rx))"
)
_RUST_LOCATION: Final = re.compile(r"\s+at /\S+:\d+\.?$")


def listen_endpoint(port: int, host: str = "127.0.0.1") -> str:
    """Return the TCP endpoint ``tcp/<host>:<port>`` (a fixed port others can connect to)."""
    if not 0 <= port <= 65535:
        raise ConfigurationError(f"port must be in 0..65535, got {port}")
    return f"tcp/{host}:{port}"


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """Return a TCP port that is free on ``host`` right now (for a rendezvous endpoint).

    Another process may take it before it is used; prefer a fixed ``--port`` when that matters.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def _endpoints(values: Sequence[str] | None, what: str) -> tuple[str, ...] | None:
    if values is None:
        return None
    if isinstance(values, str):
        values = [values]
    result = []
    for value in values:
        for item in str(value).split(","):
            item = item.strip()
            if not item:
                continue
            if "/" not in item:
                raise ConfigurationError(
                    f"{what} endpoint {item!r} must look like tcp/HOST:PORT (or udp/, tls/...)"
                )
            result.append(item)
    return tuple(result)


@dataclass(frozen=True)
class ZenohOptions:
    """How to open a Zenoh session.

    ``None`` means "from the config file if one is given, else the project default": peer
    mode, listen on ``tcp/127.0.0.1:0``, multicast scouting off.

    Attributes:
        mode: ``peer``, ``client`` or ``router``.
        connect: Endpoints to connect to, e.g. ``("tcp/127.0.0.1:7447",)``.
        listen: Endpoints to listen on (ignored in client mode).
        config_path: A Zenoh JSON5 configuration file loaded first.
        multicast_scouting: Discover peers by UDP multicast.

    """

    mode: Mode | None = None
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] | None = None
    config_path: Path | None = None
    multicast_scouting: bool | None = None

    def __post_init__(self) -> None:
        """Validate the mode and normalise the endpoint lists."""
        if self.mode is not None and self.mode not in MODES:
            raise ConfigurationError(f"zenoh mode must be one of {', '.join(MODES)}: {self.mode!r}")
        object.__setattr__(self, "connect", _endpoints(self.connect, "connect") or ())
        object.__setattr__(self, "listen", _endpoints(self.listen, "listen"))
        if self.config_path is not None:
            object.__setattr__(self, "config_path", Path(self.config_path))

    def to_config(self) -> zenoh.Config:
        """Build the ``zenoh.Config``; raise ConfigurationError if Zenoh rejects a value."""
        try:
            if self.config_path is not None:
                config = zenoh.Config.from_file(str(self.config_path))
            else:
                config = zenoh.Config()
        except zenoh.ZError as exc:
            raise ConfigurationError(
                f"{self.config_path}: cannot load zenoh config: {_zenoh_message(exc)}"
            ) from None
        from_file = self.config_path is not None
        mode = self.mode or (None if from_file else DEFAULT_MODE)
        multicast = self.multicast_scouting
        if multicast is None and not from_file:
            multicast = False
        listen = self.listen
        if listen is None and (
            not from_file or not isinstance(_json_value(config, "listen/endpoints"), list)
        ):
            # A config file that names no listen endpoint leaves Zenoh's per-mode defaults
            # (a dict: every interface): the project listens on loopback unless asked otherwise.
            listen = DEFAULT_LISTEN
        effective_mode = mode or _json_value(config, "mode") or DEFAULT_MODE
        settings: list[tuple[str, object]] = []
        if mode is not None:
            settings.append(("mode", mode))
        if self.connect:
            settings.append(("connect/endpoints", list(self.connect)))
        if listen is not None and effective_mode != "client":
            settings.append(("listen/endpoints", list(listen)))
        if multicast is not None:
            settings.append(("scouting/multicast/enabled", multicast))
        for key, value in settings:
            try:
                config.insert_json5(key, json.dumps(value))
            except zenoh.ZError as exc:
                raise ConfigurationError(
                    f"zenoh config {key}={value!r} rejected: {_zenoh_message(exc)}"
                ) from None
        return config


def _zenoh_message(exc: BaseException) -> str:
    """Zenoh's error text without the Rust source location it ends with."""
    return _RUST_LOCATION.sub("", str(exc)).strip()


def _json_value(config: zenoh.Config, key: str) -> object:
    try:
        return json.loads(config.get_json(key))
    except (zenoh.ZError, ValueError, TypeError):
        return None


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the shared ``--mode --connect --listen --config --[no-]multicast`` flags."""
    group = parser.add_argument_group("zenoh")
    group.add_argument("--mode", choices=MODES, default=None, help="session mode (default peer)")
    group.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        default=None,
        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeat or comma-separate)",
    )
    group.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        default=None,
        help="endpoint to listen on (default tcp/127.0.0.1:0, a free loopback port)",
    )
    group.add_argument(
        "--config", metavar="FILE", default=None, help="zenoh JSON5 configuration file"
    )
    group.add_argument(
        "--multicast",
        action=argparse.BooleanOptionalAction,
        dest="multicast",
        default=None,
        help="multicast scouting (default off: peers meet through --connect / --listen)",
    )


def options_from_args(args: argparse.Namespace) -> ZenohOptions:
    """Build :class:`ZenohOptions` from flags added by :func:`add_zenoh_arguments`."""
    config = getattr(args, "config", None)
    return ZenohOptions(
        mode=getattr(args, "mode", None),
        connect=_endpoints(getattr(args, "connect", None), "connect") or (),
        listen=_endpoints(getattr(args, "listen", None), "listen"),
        config_path=None if config is None else Path(config),
        multicast_scouting=getattr(args, "multicast", None),
    )


def open_session(options: ZenohOptions | None = None) -> zenoh.Session:
    """Open a Zenoh session; raise TransportError (never a raw zenoh error) on failure.

    A config file that cannot be loaded or a value Zenoh rejects raises ConfigurationError.
    """
    config = (options or ZenohOptions()).to_config()
    os.environ.setdefault("ZENOH_RUNTIME", DEFAULT_RUNTIME)
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise TransportError(f"cannot open zenoh session: {_zenoh_message(exc)}") from None
    except BaseException as exc:  # pyo3's PanicException derives from BaseException only
        if type(exc).__name__ != "PanicException":
            raise
        runtime = os.environ.get("ZENOH_RUNTIME")
        raise ConfigurationError(
            f"cannot open zenoh session: zenoh panicked ({_zenoh_message(exc)}); "
            f"is ZENOH_RUNTIME={runtime!r} valid?"
        ) from None
