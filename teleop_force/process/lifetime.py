"""Process lifetime helpers shared by the long-running commands (service, master, slave, replay).

:class:`StopSignal` turns SIGINT and SIGTERM into a flag the main loop polls, so every process
leaves through the same clean path: stop its loop, undeclare its Zenoh entities (its
liveliness token disappears at once), close recordings, write its final statistics.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any

from teleop_force.errors import DataError

#: GIL switch interval of the real-time processes [s]: a Zenoh callback waiting for the GIL
#: held by a busy loop gets it within this time (Python's default is 5 ms).
REALTIME_SWITCH_INTERVAL_S = 2e-4


#: Environment variable through which a supervisor (``teleop-force demo``) gives its children
#: its process id: a child whose parent is no longer that process stops by itself.
SUPERVISOR_PID_ENV = "TELEOP_FORCE_SUPERVISOR_PID"
#: How often an orphan check runs [s].
ORPHAN_CHECK_PERIOD_S = 0.25


def use_realtime_switch_interval() -> None:
    """Make GIL hand-overs between the loop and the Zenoh callback threads fast."""
    sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)


#: How often :meth:`StopSignal.wait` looks at the flag a signal handler set [s].
SIGNAL_POLL_PERIOD_S = 0.02


class StopSignal:
    """A stop flag set by SIGINT / SIGTERM (once installed) or by :meth:`set`.

    The signal handler takes no lock: it only assigns a flag, which :meth:`wait` and
    :meth:`is_set` read (a handler that set a ``threading.Event`` could run while the main
    thread holds that event's lock inside ``wait`` and deadlock: the process would then
    ignore every later signal).
    """

    def __init__(self) -> None:
        """Create the flag, not set."""
        self._event = threading.Event()
        self._signalled = False
        self.signal_name: str | None = None

    def install(self) -> StopSignal:
        """Handle SIGINT and SIGTERM by setting the flag (main thread only); return self."""
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, self._handle)
            signal.signal(signal.SIGTERM, self._handle)
        return self

    def watch_supervisor(self) -> StopSignal:
        """Set the flag once the supervisor named by ``$TELEOP_FORCE_SUPERVISOR_PID`` is gone.

        A backstop for ``PR_SET_PDEATHSIG``: the child polls its parent process id in a daemon
        thread, so it stops even where that signal is unavailable or was not delivered.
        Without the variable (a process started by hand) nothing is watched. Returns self.
        """
        value = os.environ.get(SUPERVISOR_PID_ENV, "")
        if not value.isdigit():
            return self
        supervisor = int(value)

        def watch() -> None:
            while not self.wait(ORPHAN_CHECK_PERIOD_S):
                if os.getppid() != supervisor:
                    self.signal_name = "supervisor gone"
                    self._event.set()

        threading.Thread(target=watch, name="orphan-watch", daemon=True).start()
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        # No lock here (class docstring): a plain assignment is safe in a signal handler.
        self.signal_name = signal.Signals(signum).name
        self._signalled = True

    def set(self) -> None:
        """Ask the process to stop."""
        self._event.set()

    def is_set(self) -> bool:
        """Whether a stop was asked for."""
        return self._signalled or self._event.is_set()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Sleep until a stop is asked for or ``timeout_s`` passes; return whether it was.

        A signal is seen within :data:`SIGNAL_POLL_PERIOD_S`; :meth:`set` at once.
        """
        deadline = None if timeout_s is None else time.monotonic() + max(0.0, timeout_s)
        while not self.is_set():
            step = SIGNAL_POLL_PERIOD_S
            if deadline is not None:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    return False
                step = min(step, remaining)
            if self._event.wait(step):
                return True
        return True


def write_json(path: str | Path, payload: Any) -> None:
    """Write ``payload`` as JSON to ``path`` (``-`` for stdout); raise DataError."""
    text = json.dumps(payload, indent=1, allow_nan=False)
    if str(path) == "-":
        print(text, flush=True)
        return
    try:
        Path(path).write_text(text + "\n")
    except OSError as exc:
        raise DataError(f"cannot write: {exc.strerror or exc}", path=path) from None


def log(prefix: str, message: str) -> None:
    """Print one log line to stderr."""
    print(f"[{prefix}] {message}", file=sys.stderr, flush=True)


def process_start_wall_ns() -> int:
    """When this process started, in ns since the UNIX epoch, to 10 ms (Linux; else: now)."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        since_boot_ns = time.clock_gettime_ns(time.CLOCK_BOOTTIME)
    except (OSError, ValueError, IndexError, AttributeError):
        return time.time_ns()
    age_ns = since_boot_ns - start_ticks * 10**9 // os.sysconf("SC_CLK_TCK")
    return time.time_ns() - age_ns
