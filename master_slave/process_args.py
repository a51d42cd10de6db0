"""Command-line flags shared by the master and slave processes (besides the Zenoh ones)."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

from master_slave.realtime import LoopConfig
from teleop_force.errors import ConfigurationError
from teleop_force.transport.session import add_zenoh_arguments


@dataclass(frozen=True)
class RunConfig:
    """How long a process runs and how it starts streaming.

    Attributes:
        duration_s: Stop after this long (``None``: until SIGINT / SIGTERM).
        wait_subscribers_s: Before streaming, wait up to this long for the main publisher
            to have a matching subscriber and for the peer process (the slave waits for the
            master's liveliness token, the master for the slave's) (0: do not wait).
        stats_json: Where to write the final statistics (``None``: nowhere, ``-``: stdout).

    """

    duration_s: float | None = None
    wait_subscribers_s: float = 0.0
    stats_json: str | None = None

    def __post_init__(self) -> None:
        """Check the ranges."""
        if self.duration_s is not None and not (
            math.isfinite(self.duration_s) and self.duration_s > 0.0
        ):
            raise ConfigurationError(f"--duration must be > 0, got {self.duration_s}")
        if not (math.isfinite(self.wait_subscribers_s) and self.wait_subscribers_s >= 0.0):
            raise ConfigurationError(
                f"--wait-subscribers must be >= 0, got {self.wait_subscribers_s}"
            )


def add_process_arguments(
    parser: argparse.ArgumentParser, *, device: str, wait_subscribers_s: float
) -> None:
    """Add ``--device --duration --rate-hz --spin-us --wait-subscribers --stats-json`` + Zenoh."""
    parser.add_argument("--device", default=device, help=f"device id (default {device})")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="run S seconds (default: until Ctrl-C)",
    )
    parser.add_argument("--rate-hz", type=float, default=1000.0, help="control rate (default 1000)")
    parser.add_argument(
        "--spin-us",
        type=float,
        default=0.0,
        help="busy-wait this long before each deadline instead of sleeping "
        "(default 0: sleep to the deadline, no core spinning)",
    )
    parser.add_argument(
        "--wait-subscribers",
        type=float,
        default=wait_subscribers_s,
        metavar="S",
        help="wait up to S seconds for a matching subscriber and the peer process (master "
        "or slave) before streaming "
        f"(default {wait_subscribers_s:g}; 0: start at once)",
    )
    parser.add_argument(
        "--stats-json",
        default=None,
        metavar="PATH",
        help="write the final statistics as JSON (- = stdout)",
    )
    add_zenoh_arguments(parser)


def loop_config_from_args(args: argparse.Namespace) -> LoopConfig:
    """Return the :class:`LoopConfig` of the parsed flags (a process's loop: heap frozen)."""
    return LoopConfig(rate_hz=args.rate_hz, spin_s=args.spin_us * 1e-6, freeze_gc=True)


def run_config_from_args(args: argparse.Namespace) -> RunConfig:
    """Return the :class:`RunConfig` of the parsed flags."""
    return RunConfig(
        duration_s=args.duration,
        wait_subscribers_s=args.wait_subscribers,
        stats_json=args.stats_json,
    )


def add_plant_effect_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--plant-effect NAME`` and its ``-at-s``, ``-scale``, ``-joint`` (slave and demo)."""
    parser.add_argument(
        "--plant-effect", default=None, metavar="NAME",
        help="switch this simulated effect on in the slave's plant mid-session, for the "
        "service's residual watch (a name of teleop_force.simulation.EFFECT_NAMES: "
        "cogging, position-friction, drifting-friction, load-friction, elbow-bump, ...)",
    )  # fmt: skip
    parser.add_argument(
        "--plant-effect-at-s", type=float, default=60.0, metavar="S",
        help="when, in seconds of the slave's loop (default 60)",
    )  # fmt: skip
    parser.add_argument(
        "--plant-effect-scale", type=float, default=0.1, metavar="X",
        help="the effect's RMS as a fraction of the joint's RMS commanded torque (default 0.1)",
    )  # fmt: skip
    parser.add_argument(
        "--plant-effect-joint", type=int, default=None, metavar="J",
        help="the effect's joint, 1-based (default: the effect's own)",
    )  # fmt: skip
