"""A Zenoh router in a Python process: the rendezvous point of clients across machines.

    python -m teleop_force.transport.router --listen tcp/127.0.0.1:7447
    python -m master_slave.slave --mode client --connect tcp/127.0.0.1:7447 ...

It opens one session in router mode, listening on ``--listen`` (default
``tcp/127.0.0.1:7447``: loopback only; give ``tcp/0.0.0.0:7447`` to serve other machines, and
see ``docs/reliability.md`` for TLS and access control through ``--config``), with multicast
scouting off, and routes until SIGINT / SIGTERM or ``--duration``. Clients that lose it
reconnect by themselves when it comes back (Zenoh retries the ``connect`` endpoints), so
restarting the router interrupts the streams without stopping any process. ``zenohd`` does
the same job; this exists so that nothing but this package is needed.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Final

from teleop_force.errors import ConfigurationError, TeleopForceError
from teleop_force.process.lifetime import StopSignal, log
from teleop_force.transport.pubsub import close_session
from teleop_force.transport.session import ZenohOptions, open_session

ROLE: Final = "router"
DEFAULT_ROUTER_LISTEN: Final = "tcp/127.0.0.1:7447"


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``python -m teleop_force.transport.router``."""
    parser = argparse.ArgumentParser(
        prog="python -m teleop_force.transport.router", description=__doc__.splitlines()[0]
    )
    parser.add_argument(
        "--listen", action="append", default=None, metavar="ENDPOINT",
        help=f"endpoint to listen on (repeatable; default {DEFAULT_ROUTER_LISTEN})",
    )  # fmt: skip
    parser.add_argument(
        "--connect", action="append", default=[], metavar="ENDPOINT",
        help="another router to connect to (repeatable)",
    )  # fmt: skip
    parser.add_argument(
        "--config", default=None, metavar="FILE",
        help="zenoh JSON5 configuration (TLS certificates, access control...)",
    )  # fmt: skip
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Route until SIGINT / SIGTERM or ``--duration``; return the exit status."""
    args = build_parser().parse_args(argv)
    stop = StopSignal().install().watch_supervisor()
    try:
        if args.duration is not None and not args.duration > 0:
            raise ConfigurationError(f"--duration must be > 0, got {args.duration}")
        listen = tuple(args.listen) if args.listen else (DEFAULT_ROUTER_LISTEN,)
        options = ZenohOptions(
            mode="router",
            listen=listen,
            connect=tuple(args.connect),
            config_path=None if args.config is None else Path(args.config),
            multicast_scouting=False,
        )
        session = open_session(options)
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    try:
        log(ROLE, f"routing on {', '.join(listen)}")
        stop.wait(args.duration)
    finally:
        close_session(session)
    log(ROLE, "stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
