"""A watchdog that outlives a process commanding a driver's force: zero force when it dies.

sawSensablePhantom keeps the last ``servo_cf`` with no timeout (docs/real_robot.md). A process
that commands forces and is killed (SIGKILL, a crash, the machine's OOM killer) would leave
the operator's hand pushed by its last force. :func:`start_force_watchdog` starts this module
as a child process holding the read end of a pipe whose write end only the parent holds. The
kernel closes that end whatever kills the parent, so the child reads end-of-file and then
publishes, on the driver's topics, a zero WrenchStamped on ``/<device>/servo_cf`` and a
``std_msgs/msg/Empty`` on ``/<device>/free`` (:data:`REPEATS` times, :data:`REPEAT_PERIOD_S`
apart, in case one is lost), and exits. Its session and publishers are open before the parent
is told it is ready, so nothing is opened after the death.

    python -m master_slave.force_watchdog --device master --connect tcp/127.0.0.1:7447

(the parent's end is the child's standard input; ``ready`` on standard output once armed).
"""

from __future__ import annotations

import argparse
import os
import select
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import IO, Final

from teleop_force.errors import TeleopForceError, TransportError
from teleop_force.process.lifetime import log
from teleop_force.ros2 import interfaces
from teleop_force.ros2 import topics as ros2_topics
from teleop_force.ros2.codec import encode_empty, encode_wrench
from teleop_force.ros2.node import Node
from teleop_force.transport.session import (
    ZenohOptions,
    add_zenoh_arguments,
    open_session,
    options_from_args,
)

ROLE: Final = "force-watchdog"
#: The driver's command topics (sawSensablePhantom's CRTK names).
SERVO_CF: Final = "servo_cf"
FREE: Final = "free"
HOLD: Final = "hold"
#: How many times the zero force and ``free`` are sent, and how far apart [s].
REPEATS: Final = 5
REPEAT_PERIOD_S: Final = 0.02
READY_LINE: Final = b"ready\n"


class ZeroForceSender:
    """Publishers of a zero ``servo_cf`` and of ``free`` for one driver, opened in advance."""

    def __init__(self, node: Node, device: str) -> None:
        """Declare the two publishers on ``node`` for driver ``device``."""
        self.device = ros2_topics.validate_device(device)
        #: The driver's ``servo_cf`` publisher (a process commanding forces shares it).
        self.servo_cf = node.publisher(f"/{self.device}/{SERVO_CF}", interfaces.WRENCH_STAMPED)
        self._free = node.publisher(f"/{self.device}/{FREE}", interfaces.EMPTY)
        self._empty = encode_empty()

    def send(self, repeats: int = REPEATS, period_s: float = REPEAT_PERIOD_S) -> None:
        """Publish a zero force then ``free``, ``repeats`` times."""
        for i in range(repeats):
            zero = encode_wrench(time.time_ns(), (0.0, 0.0, 0.0), ros2_topics.BASE_FRAME)
            self.servo_cf.publish(zero)
            self._free.publish(self._empty)
            if i + 1 < repeats:
                time.sleep(period_s)


@dataclass
class ForceWatchdog:
    """The parent's handle on its watchdog: closing the pipe (or dying) fires it."""

    process: subprocess.Popen[bytes]
    _pipe: IO[bytes]

    def release(self, timeout_s: float = 5.0) -> int | None:
        """Fire the watchdog now (a clean exit): close the pipe, wait for the child."""
        if not self._pipe.closed:
            self._pipe.close()
        try:
            return self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return None


def start_force_watchdog(
    device: str, connect: Sequence[str], *, hold: Sequence[str] = (), timeout_s: float = 20.0
) -> ForceWatchdog:
    """Start the watchdog child for driver ``device``; return once it is armed.

    ``connect``: the Zenoh endpoints the child connects to (the driver's router or peer).
    ``hold``: drivers that are sent ``hold`` as well (a slave following the dead process).
    Raises TransportError if the child does not report ready within ``timeout_s``.
    """
    argv = [sys.executable, "-m", "master_slave.force_watchdog", "--device", device]
    for endpoint in connect:
        argv += ["--connect", endpoint]
    for name in hold:
        argv += ["--hold", name]
    argv += ["--no-multicast"]
    # own process group: a Ctrl-C to the parent's group does not fire it before the parent's
    # own clean stop (which fires it anyway)
    process = subprocess.Popen(
        argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True
    )
    assert process.stdin is not None and process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    line = process.stdout.readline() if ready else b""
    if line != READY_LINE:
        process.kill()
        raise TransportError(
            f"the force watchdog for {device!r} did not arm within {timeout_s:g} s "
            f"(exit code {process.poll()})"
        )
    return ForceWatchdog(process, process.stdin)


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of ``python -m master_slave.force_watchdog``."""
    parser = argparse.ArgumentParser(
        prog="python -m master_slave.force_watchdog", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--device", required=True, help="the driver's namespace, e.g. master")
    parser.add_argument(
        "--hold", action="append", default=[], metavar="DEVICE",
        help="a driver sent hold too (repeatable), e.g. the slave",
    )  # fmt: skip
    add_zenoh_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Arm, wait for the parent's end of the pipe to close, send zero force and free."""
    args = build_parser().parse_args(argv)
    try:
        options: ZenohOptions = options_from_args(args)
        session = open_session(options)
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    try:
        node = Node(session, "teleop_force_force_watchdog")
        sender = ZeroForceSender(node, args.device)
        empty = encode_empty()
        holds = [
            node.publisher(f"/{ros2_topics.validate_device(name)}/{HOLD}", interfaces.EMPTY)
            for name in args.hold
        ]
        os.write(sys.stdout.fileno(), READY_LINE)
        stdin = sys.stdin.buffer
        while stdin.read(4096):  # the parent never writes: returns b"" when it is gone
            pass
        sender.send()
        for publisher in holds:
            publisher.publish(empty)
        log(ROLE, f"parent gone: zero force and free sent to /{args.device}")
        node.close()
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
