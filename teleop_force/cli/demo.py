r"""``teleop-force demo``: master, slave, service (and dashboard) on loopback, supervised.

The supervisor opens the rendezvous Zenoh endpoint ``tcp/127.0.0.1:<free port>`` (peer mode,
multicast scouting off); every child is a peer that ``--connect``\\ s to it, and Zenoh's gossip
lets the peers connect to one another. On a machine whose numba cache does not hold the
children's compiled kernels yet, they are compiled in parallel processes, one per core, with a
progress line per group on stderr (:mod:`teleop_force.process.warm_up`); each child starts
once the groups it runs are compiled (the recorder at once), and loads them before it declares
itself up. The children start together otherwise (their imports overlap); each one's
liveliness token tells the supervisor it is up:

1. the force-estimation service (``python -m teleop_force.service.force_service``), recording
   the session to ``recordings/demo-<timestamp>.mcap``;
2. the slave (``python -m master_slave.slave``), which starts streaming once the service
   subscribes to its joint states;
3. the master (``python -m master_slave.master``), which starts once the slave subscribes to
   its setpoints;
4. the dashboard (``python -m web --device slave --port P --connect <endpoint>``) unless
   ``--headless``, or with a message if ``web/__main__.py`` does not exist yet.

Every second it prints the service's figures (estimated vs true force, rates, lost messages,
latencies). After ``--duration`` (counted from the service's first estimate) or on Ctrl-C /
SIGTERM it collects the final statistics, stops the children (master first) and prints the summary:
messages lost, master -> slave latency, slave -> estimate latency, the force-estimate RMS
error during contact as a fraction of the RMS true force, the master's and slave's loop
figures, the slave's holds and the CPU used (``--summary-json`` writes it too).

Real time on a shared machine
-----------------------------
A 1 kHz loop on a loaded 2-core machine waits for a CPU for tens of milliseconds at a time
under ordinary scheduling, whatever its own cost (measured: 10-20 % of the ticks late by more
than a period at load 4-6, even at nice -10). So the service, the slave and the master run in
the ``SCHED_FIFO`` real-time class (``rt_priority``, default 10 for the service and 11 for
the loops, which preempt the service's estimation), *every thread* of them: a loop thread
alone in that class would wait on Zenoh threads that are not. This needs root,
``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO``; without, they run at ``realtime_nice`` (-10, also
privileged) or as they are: ``scheduling`` in the summary says what they got. The kernel
keeps 5 % of every CPU for ordinary work whatever the real-time tasks do
(``sched_rt_runtime_us``). The supervisor itself runs at ``realtime_nice``: starved, it would
stop reading its sockets and the publishers it subscribes to (congestion control BLOCK) would
wait for it.

The figures of the slave's estimates (loss, accuracy during contact, the first estimate, the
slave's state) are kept by the session recorder, which receives every message anyway
(``--monitor``, :class:`~teleop_force.service.session_monitor.SessionMonitor`); the
supervisor asks its statistics queryable for them (:class:`_RecorderMonitor`) and receives
no 1 kHz stream itself. With ``--no-record`` the supervisor subscribes itself: ring channels
(no Python on Zenoh's receive threads) drained by one thread every 50 ms (:class:`_Monitor`).
The summary's ``estimates_at_supervisor`` and ``true_forces_at_supervisor`` are those
figures, whichever process kept them.

Summary JSON
------------
``ok``, ``failure``; ``duration_s`` (from the first estimate); ``first_estimate_s`` (from the
command's start to the first estimate the supervisor received); ``up_after_s`` {name: s from
the command's start to its token, ``None``: never}; ``warm_up`` (``cached``, ``seconds``,
``groups`` {name: {``seconds``, ``ok``}}); ``estimate_coverage`` {``sent_by_slave``,
``received_by_service``, ``lost_on_the_way``, ``dropped_by_service``, ``estimation_errors``,
``estimated``, ``estimated_fraction``}: the summary says plainly when the service estimated
fewer than 99 % of the joint states the slave sent, and why; ``recording``, ``log``,
``zenoh_endpoint``, ``pids`` {name: pid}; ``scheduling`` {name: {``policy`` (``fifo`` /
``other``), ``priority``, ``nice``}};

- ``messages_lost`` {``setpoints_at_slave``, ``joint_states_at_service``,
  ``joint_states_dropped_by_service``, ``estimates_at_supervisor``,
  ``true_forces_at_supervisor``, ``total``};
- ``master_to_slave_latency_ms``, ``slave_to_estimate_latency_ms`` {``p50``, ``p99``,
  ``max``, ``count``};
- ``force_error`` (:meth:`~teleop_force.service.accuracy.ForceAccuracy.summary`);
- ``loops`` {``master``, ``slave``: {``ticks``, ``expected_ticks`` (the loop's elapsed time
  x its rate), ``ticks_fraction`` (ticks / expected), ``overruns`` (ticks started more than a
  period late), ``overrun_fraction`` (overruns / ticks), ``missed_ticks`` (deadlines a resync
  jumped over), ``resyncs``, ``rate_hz``, ``gc_full_collections``, ``lateness_ms`` {``p50``,
  ``p99``, ``max``, ``count``}}} (:meth:`master_slave.realtime.RateLoop.stats`);
- ``loop_overruns`` {``master``, ``slave``} (counts) and ``loop_overrun_fraction`` {``master``,
  ``slave``};
- ``slave_holds``; ``malformed_dropped`` {``service``, ``slave``, ``supervisor``};
  ``rates_hz`` {``joint_states_at_service``, ``slave_loop``, ``master_loop``};
- ``cpu_percent`` {``service``, ``slave``, ``master``, ``supervisor``, ``dashboard`` if it
  ran, ``total``}: CPU time over the running phase in % of one core
  (``cpu_percent_of_one_core``: the same dict, its older name);
- ``machine_load_average`` (at the end) and ``machine_load_average_at_start`` [1, 5, 15 min];
- ``stats``: the final statistics of the service, the slave and the master.

Children run in their own process groups (a terminal's Ctrl-C reaches only the supervisor,
which stops them in order); each group gets SIGTERM, then SIGKILL after a timeout. If the
supervisor itself dies, the children stop by themselves: on Linux they get SIGTERM
(``PR_SET_PDEATHSIG``), and in any case they watch their parent
(``$TELEOP_FORCE_SUPERVISOR_PID``) and stop within a quarter of a second of it going away.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import importlib.util
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import IO, Any, Final

import zenoh

from teleop_force.errors import ConfigurationError, DataError, TransportError
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.process.lifetime import (
    SUPERVISOR_PID_ENV,
    StopSignal,
    process_start_wall_ns,
    write_json,
)
from teleop_force.process.warm_up import (
    KERNEL_GROUPS,
    GroupTiming,
    WarmUpReport,
    is_warm,
    warm_up,
)
from teleop_force.ros2 import topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, QueueSubscription
from teleop_force.service.accuracy import AccuracyConfig, ForceAccuracy
from teleop_force.service.session_monitor import MONITORED, SessionMonitor
from teleop_force.transport import keys
from teleop_force.transport.pubsub import (
    declare_liveliness_subscriber,
    query_json,
    undeclare_all,
)
from teleop_force.transport.session import (
    ZenohOptions,
    listen_endpoint,
    open_session,
)

DEFAULT_DASHBOARD_PORT: Final = 8080
#: rmw_zenoh's router port (``rmw_zenohd``; its nodes connect to ``tcp/localhost:7447``).
ROS2_ROUTER_PORT: Final = 7447
#: SCHED_FIFO priority of the real-time children (service, slave, master) by default.
DEFAULT_RT_PRIORITY: Final = 10
#: Their nice value when the real-time class is off or not allowed.
DEFAULT_REALTIME_NICE: Final = -10
_PR_SET_PDEATHSIG: Final = 1
_STOP_TIMEOUT_S: Final = 5.0


@dataclass(frozen=True)
class DemoConfig:
    """Settings of :func:`run_demo`.

    Attributes:
        duration_s: Run this long from the first estimate (``None``: until Ctrl-C).
        headless: Do not start the dashboard.
        dashboard_port: HTTP port of the dashboard.
        zenoh_port: Port of the Zenoh router every process connects to (``None``:
            ``ROS2_ROUTER_PORT``, 7447, rmw_zenoh's default, where ROS 2 nodes find it). The
            demo starts ``python -m teleop_force.transport.router`` there when the port is
            free, and joins the router already listening there (``rmw_zenohd``) when not.
        model: Model for the service (``None``: the shipped one).
        record_dir: Where the session is recorded.
        summary_json: Where to write the final summary as JSON.
        master: Device id of the master.
        slave: Device id of the slave.
        motion: Operator script of the master (``palpation`` or ``random``).
        haptic_feedback: Feed the estimated force back to the master.
        surface_y_m: Height of the slave's tissue (and of the operator's palpation script).
        startup_timeout_s: Longest wait for a child to come up.
        report_period_s: Period of the figures printed while running (0: none).
        accuracy: Contact threshold of the accuracy figure.
        rt_priority: ``SCHED_FIFO`` priority of the service, the slave and the master, all
            their threads (0: ordinary scheduling). A 1 kHz loop on a loaded 2-core machine
            otherwise waits for a CPU for tens of milliseconds at a time (module docstring).
            Needs root, ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO``; without, the children run
            at ``realtime_nice``.
        service_args: Extra arguments of the service process (``--adapt``,
            ``--zenoh-floor``...).
        slave_args: Extra arguments of the slave process (``--plant-effect NAME
            --plant-effect-at-s S --plant-effect-scale X``: a simulated effect switched on
            mid-session, for the service's residual watch; ``--seed N``: its actuator noise).
        master_args: Extra arguments of the master process (``--seed N``: the operator's
            script).
        record: Record the session (every message, by the service, to ``record_dir``).
        realtime_nice: Nice value of the service, the slave and the master (``None``: the
            supervisor's); it matters when they do not run in the real-time class. A
            negative value needs the same privilege.

    """

    duration_s: float | None = None
    headless: bool = False
    dashboard_port: int = DEFAULT_DASHBOARD_PORT
    zenoh_port: int | None = None
    model: Path | None = None
    record_dir: Path = Path("recordings")
    summary_json: Path | None = None
    master: str = "master"
    slave: str = "slave"
    motion: str = "palpation"
    haptic_feedback: bool = False
    surface_y_m: float = -0.06
    startup_timeout_s: float = 90.0
    report_period_s: float = 1.0
    accuracy: AccuracyConfig = field(default_factory=AccuracyConfig)
    rt_priority: int = DEFAULT_RT_PRIORITY
    realtime_nice: int | None = DEFAULT_REALTIME_NICE
    service_args: tuple[str, ...] = ()
    slave_args: tuple[str, ...] = ()
    master_args: tuple[str, ...] = ()
    record: bool = True

    def __post_init__(self) -> None:
        """Check the ranges and ids."""
        if self.realtime_nice is not None and not -20 <= self.realtime_nice <= 19:
            raise ConfigurationError(f"--nice must be in -20..19, got {self.realtime_nice}")
        if not 0 <= self.rt_priority <= 99:
            raise ConfigurationError(f"--rt-priority must be in 0..99, got {self.rt_priority}")
        if self.duration_s is not None and not (
            math.isfinite(self.duration_s) and self.duration_s > 0.0
        ):
            raise ConfigurationError(f"--duration must be > 0, got {self.duration_s}")
        if not 1 <= self.dashboard_port <= 65535:
            raise ConfigurationError(f"--port must be in 1..65535, got {self.dashboard_port}")
        if self.zenoh_port is not None and not 1 <= self.zenoh_port <= 65535:
            raise ConfigurationError(f"--zenoh-port must be in 1..65535, got {self.zenoh_port}")
        keys.validate_chunk(self.master)
        keys.validate_chunk(self.slave)
        if self.master == self.slave:
            raise ConfigurationError("master and slave need different device ids")
        if not self.startup_timeout_s > 0.0 or self.report_period_s < 0.0:
            raise ConfigurationError("startup_timeout_s must be > 0 and report_period_s >= 0")


# ------------------------------------------------------------------------------ children


def _accepts_connections(endpoint: str) -> bool:
    """Return whether something accepts TCP connections on ``tcp/<host>:<port>`` now."""
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    try:
        with socket.create_connection((host, int(port)), 0.2):
            return True
    except OSError:
        return False


def _die_with_parent() -> None:  # pragma: no cover - runs in the forked child
    """Ask the kernel to SIGTERM this child when the supervisor dies (Linux only)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        return


@dataclass(frozen=True)
class _ChildSetup:
    """What a child runs after the fork, before ``exec``: die with the parent, scheduling.

    The nice value and the ``SCHED_FIFO`` class are set before the child has any thread, so
    every thread it starts (Zenoh's included) inherits them: a loop thread alone in the
    real-time class would wait on Zenoh threads that are not. What the process lacks the
    privilege for is left as it was; :meth:`Child.scheduling` reads what it got.
    """

    nice: int | None = None
    rt_priority: int = 0

    def __call__(self) -> None:  # pragma: no cover - runs in the forked child
        if sys.platform.startswith("linux"):
            _die_with_parent()
        if self.nice is not None:
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, 0, self.nice)
        if self.rt_priority > 0 and hasattr(os, "sched_setscheduler"):
            with contextlib.suppress(OSError):
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))


class Child:
    """One supervised child process in its own process group."""

    def __init__(
        self,
        name: str,
        argv: list[str],
        log: IO[bytes],
        *,
        nice: int | None = None,
        rt_priority: int = 0,
    ) -> None:
        """Start ``argv`` (at ``nice``, in SCHED_FIFO at ``rt_priority`` > 0, where allowed).

        Its output goes to ``log``.
        """
        self.name = name
        self.argv = argv
        environment = {**os.environ, SUPERVISOR_PID_ENV: str(os.getpid())}
        try:
            self.process = subprocess.Popen(
                argv,
                env=environment,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
                start_new_session=True,
                preexec_fn=_ChildSetup(nice, rt_priority),
            )
        except OSError as exc:
            raise TransportError(f"cannot start {name}: {exc}") from None
        self._stopped = False

    def scheduling(self) -> dict[str, Any] | None:
        """``{"policy": "fifo" | "other" | ..., "priority", "nice"}`` (``None``: gone)."""
        try:
            nice = os.getpriority(os.PRIO_PROCESS, self.pid)
            if not hasattr(os, "sched_getscheduler"):
                return {"policy": None, "priority": None, "nice": nice}
            policy = os.sched_getscheduler(self.pid)
            priority = os.sched_getparam(self.pid).sched_priority
        except OSError:
            return None
        names = {os.SCHED_FIFO: "fifo", os.SCHED_RR: "rr", os.SCHED_OTHER: "other"}
        return {"policy": names.get(policy, str(policy)), "priority": priority, "nice": nice}

    @property
    def pid(self) -> int:
        """Process id (also its process-group id)."""
        return self.process.pid

    def cpu_s(self) -> float | None:
        """CPU time (user + system) the process has used so far [s] (Linux; else ``None``)."""
        try:
            with open(f"/proc/{self.pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            return None
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def running(self) -> bool:
        """Whether the process has not exited."""
        return self.process.poll() is None

    def signal_group(self, signum: int) -> None:
        """Send ``signum`` to the child's whole process group (if it still exists)."""
        try:
            os.killpg(self.pid, signum)
        except (ProcessLookupError, PermissionError):
            return

    def stop(self, timeout_s: float = _STOP_TIMEOUT_S) -> int | None:
        """SIGTERM the group, SIGKILL it after ``timeout_s``; return the exit code (idempotent)."""
        if self._stopped:
            return self.process.returncode
        self._stopped = True
        if self.running():
            self.signal_group(signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.signal_group(signal.SIGKILL)
                self.process.wait(timeout_s)
        # Anything the child left in its group goes too.
        self.signal_group(signal.SIGKILL)
        return self.process.returncode


def dashboard_available() -> bool:
    """Whether ``python -m web`` can run (``web/__main__.py`` exists)."""
    try:
        return importlib.util.find_spec("web.__main__") is not None
    except (ImportError, ValueError):
        return False


# ------------------------------------------------------------------------------ supervisor


class _Presence:
    """Liveliness tokens currently present."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.present: set[str] = set()
        #: When each token was first seen (ns since the epoch).
        self.first_seen_ns: dict[str, int] = {}

    def on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.present.add(key)
                self.first_seen_ns.setdefault(key, time.time_ns())
            else:
                self.present.discard(key)

    def has(self, key: str) -> bool:
        with self._lock:
            return key in self.present


#: Samples a monitor channel holds (about 30 s of a 2 kHz stall); beyond, the oldest go
#: (and count as lost): the supervisor never blocks a publisher.
_CHANNEL_CAPACITY: Final = 1 << 16
#: Where each process listens for its peers' direct links (a free port on loopback).
_ANY_LOOPBACK_PORT: Final = "tcp/127.0.0.1:0"
#: How often the monitor drains its channels [s].
_DRAIN_PERIOD_S: Final = 0.05
#: How often the supervisor asks the recorder for the figures while waiting for the first
#: estimate [s].
_FIRST_ESTIMATE_POLL_S: Final = 0.05


class _Monitor:
    """The supervisor's own ROS 2 subscriptions to the slave's estimates, true forces, status.

    For a demo that does not record (the recorder keeps the figures otherwise:
    :class:`_RecorderMonitor`). Cheap by construction: the subscriptions queue samples in
    Zenoh's ring channels (no Python, no GIL on Zenoh's receive threads), and one worker
    thread drains them every ``_DRAIN_PERIOD_S`` into a
    :class:`~teleop_force.service.session_monitor.SessionMonitor`.
    """

    def __init__(self, slave: str, accuracy: AccuracyConfig) -> None:
        self.session_monitor = SessionMonitor(slave, accuracy)
        self._node: Node | None = None
        self._subscriptions: list[tuple[QueueSubscription, Callable[[bytes, Attachment], None]]]
        self._subscriptions = []
        self._lock = threading.Lock()  # one drain at a time (worker, final drain)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="monitor", daemon=True)
        self._channel_malformed = 0

    def subscribe(self, session: zenoh.Session) -> list[Any]:
        """Declare the node and its ring-channel subscriptions, start the worker."""
        monitor = self.session_monitor
        node = self._node = Node(session, "teleop_force_demo")
        for topic in MONITORED:
            name = topics.topic_name(monitor.device, topic)
            handle = monitor.handler(name)
            assert handle is not None
            subscription = node.queue_subscription(name, topic.ros_type, _CHANNEL_CAPACITY)
            self._subscriptions.append((subscription, handle))
        self._thread.start()
        return []

    def first_estimate(self) -> tuple[int, int] | None:
        """``(header stamp [ns], source seq)`` of the first estimate, ``None`` before it."""
        monitor = self.session_monitor
        if monitor.first_estimate_ns is None or monitor.first_source_seq is None:
            return None
        return monitor.first_estimate_ns, monitor.first_source_seq

    def figures(self, final: bool = False) -> dict[str, Any] | None:
        """Return :meth:`SessionMonitor.figures`, with the samples the channels dropped."""
        with self._lock:
            figures = self.session_monitor.figures()
        figures["malformed"] += self._channel_malformed
        return figures

    def drain(self) -> None:
        """Process every sample received so far."""
        monitor = self.session_monitor
        with self._lock:
            for subscription, handle in self._subscriptions:
                while (received := subscription.try_recv()) is not None:
                    monitor.take(handle, *received)

    def close(self) -> None:
        """Stop the worker thread after a last drain, then undeclare the node."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        self.drain()
        node, self._node = self._node, None
        if node is not None:
            node.close()
        self._channel_malformed += sum(s.malformed for s, _ in self._subscriptions)
        self._subscriptions = []

    def _run(self) -> None:
        while not self._stop.wait(_DRAIN_PERIOD_S):
            self.drain()


class _RecorderMonitor:
    """The figures of :class:`_Monitor`, kept by the session recorder (``--monitor``).

    The recorder receives every message anyway; the supervisor asks it for the figures on its
    statistics queryable instead of receiving the 1 kHz streams a second time.
    """

    def __init__(self, query: Callable[[str, float], dict[str, Any] | None], slave: str) -> None:
        self._query = query
        self._key = keys.process_stats(slave, "recorder")
        self._last: dict[str, Any] | None = None
        self._asked_s = -math.inf

    def subscribe(self, session: zenoh.Session) -> list[Any]:
        """Nothing to declare: the recorder keeps the figures."""
        return []

    def close(self) -> None:
        """Nothing to undeclare."""

    def figures(self, final: bool = False) -> dict[str, Any] | None:
        """Ask the recorder (it drains first); the last answer if it does not answer."""
        stats = self._query(self._key, 2.0 if final else 0.5)
        monitor = (stats or {}).get("monitor")
        if isinstance(monitor, dict):
            self._last = monitor
        return self._last

    def first_estimate(self) -> tuple[int, int] | None:
        """``(header stamp [ns], source seq)`` of the first estimate, ``None`` before it."""
        now = time.perf_counter()
        if now - self._asked_s >= _FIRST_ESTIMATE_POLL_S:
            self._asked_s = now
            self.figures()
        last = self._last or {}
        stamp, seq = last.get("first_estimate_ns"), last.get("first_source_seq")
        return None if stamp is None or seq is None else (int(stamp), int(seq))


_LOOP_KEYS: Final = (
    "ticks", "expected_ticks", "ticks_fraction", "overruns", "overrun_fraction",
    "missed_ticks", "resyncs", "rate_hz", "gc_full_collections",
)  # fmt: skip


def _loop_summary(stats: dict[str, Any] | None) -> dict[str, Any]:
    """Pick the loop figures of a master's or slave's final statistics (``None``: unknown)."""
    loop = (stats or {}).get("loop") or {}
    summary = {key: loop.get(key) for key in _LOOP_KEYS}
    summary["lateness_ms"] = loop.get("lateness_ms")
    return summary


def _fmt_loop(loop: dict[str, Any]) -> str:
    if loop.get("ticks") is None:
        return "n/a"
    fraction, overrun = loop.get("ticks_fraction"), loop.get("overrun_fraction")
    ticks = f"{loop['ticks']} ticks of {loop['expected_ticks']:.0f} expected"
    if fraction is not None:
        ticks += f" ({fraction:.2%})"
    overruns = f"overruns {loop['overruns']}"
    if overrun is not None:
        overruns += f" ({overrun:.2%})"
    return f"{ticks}, {overruns}, missed {loop['missed_ticks']}"


def _python_module(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]


def _fmt_force(force: Sequence[float] | None) -> str:
    if force is None:
        return "(   -  ,   -  ,   -  )"
    return "(" + ",".join(f"{x:+6.2f}" if math.isfinite(x) else "  nan " for x in force) + ")"


def _ms(summary: dict[str, Any] | None, key: str) -> str:
    value = None if summary is None else summary.get(key)
    return "-" if value is None else f"{value:.2f}"


class DemoSupervisor:
    """Starts, watches and stops the demo's processes (module docstring)."""

    def __init__(self, config: DemoConfig, stop: StopSignal, out: IO[str] | None = None) -> None:
        """Prepare; :meth:`run` does the work."""
        self.config = config
        self.stop = stop
        self.out = out if out is not None else sys.stdout
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        self.recording = config.record_dir / f"demo-{stamp}.mcap"
        self.log_path = config.record_dir / f"demo-{stamp}.log"
        self.children: list[Child] = []
        self.presence = _Presence()
        self.monitor: _Monitor | _RecorderMonitor = (
            _RecorderMonitor(self._query, config.slave)
            if config.record
            else _Monitor(config.slave, config.accuracy)
        )
        self.session: zenoh.Session | None = None
        self.endpoint = ""
        self.failure = ""
        self.started_s = 0.0
        self.running_s = 0.0
        self.ended_s = 0.0
        self.cpu_percent: dict[str, float | None] = {}
        self._recorder_stats: dict[str, Any] | None = None
        self._cpu_at_run: dict[str, float | None] = {}
        self._own_cpu_at_run = 0.0
        self._load_at_run: list[float] | None = None
        self._scheduling: dict[str, dict[str, Any] | None] = {}
        self.warm_up_report: WarmUpReport | None = None
        self._warm_up_thread: threading.Thread | None = None
        #: Kernel groups compiled so far, under their condition (the warm-up's thread sets it).
        self._compiled_groups = threading.Condition()
        self._compiled_names: set[str] = set()
        #: The liveliness token each started child was waited for by.
        self._tokens: dict[str, str] = {}
        #: Seconds from this process's start to the first estimate (``None``: none came).
        self.first_estimate_s: float | None = None
        self._start_wall_ns = process_start_wall_ns()

    def say(self, message: str) -> None:
        """Print one line for the user."""
        print(message, file=self.out, flush=True)

    # -- lifetime -------------------------------------------------------------------------------

    def run(self) -> dict[str, Any]:
        """Run the demo to the end; return the summary (also printed)."""
        config = self.config
        try:
            config.record_dir.mkdir(parents=True, exist_ok=True)
            log = open(self.log_path, "ab")  # noqa: SIM115 - closed below
        except OSError as exc:
            raise DataError(f"cannot write: {exc.strerror or exc}", path=self.log_path) from None
        with log:
            return self._run(log)

    def _run(self, log: IO[bytes]) -> dict[str, Any]:
        config = self.config
        if config.realtime_nice is not None:
            # Before Zenoh's threads exist, so they inherit it: a supervisor starved by the
            # machine's other work stops reading its sockets, and the publishers it
            # subscribes to (congestion control BLOCK) then wait for it.
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, 0, config.realtime_nice)
        self.endpoint = listen_endpoint(config.zenoh_port or ROS2_ROUTER_PORT)
        if _accepts_connections(self.endpoint):
            self.say(f"joining the Zenoh router already on {self.endpoint}")
        else:
            self._start_router(log)
        options = ZenohOptions(
            mode="peer", connect=(self.endpoint,), listen=(_ANY_LOOPBACK_PORT,),
            multicast_scouting=False,
        )  # fmt: skip
        self.session = open_session(options)
        entities: list[Any] = []
        final: dict[str, Any] = {}
        try:
            entities.append(
                declare_liveliness_subscriber(
                    self.session, keys.alive_any(), self.presence.on_sample
                )
            )
            entities += self.monitor.subscribe(self.session)
            self.say(
                f"zenoh router: {self.endpoint} (the processes are its peers, linked directly "
                "to each other; ROS 2 nodes its clients; no multicast)"
            )
            self.say(f"recording: {self.recording}   logs: {self.log_path}")
            self._warm_up()
            if self._start_all(log) and self._wait_for_first_estimate():
                self._watch()
            self.ended_s = time.perf_counter()
            final = self._final_stats()
            self._stop_children()
        finally:
            self._stop_children()
            self.monitor.close()  # the last samples, before the subscribers go
            undeclare_all(*entities)
            self.session.close()
        summary = self._summary(final)
        self._print_summary(summary)
        if config.summary_json is not None:
            write_json(config.summary_json, summary)
        return summary

    def _warm_up(self) -> None:
        """Compile the children's kernels in parallel, unless they are cached, in a thread.

        Progress goes to stderr, one line per kernel group; each child starts once the groups
        it runs are compiled (:meth:`_wait_for_kernels`), and then only loads them.
        """
        if is_warm(self.config.model):
            self.warm_up_report = WarmUpReport(cached=True, seconds=0.0)
            return
        self._warm_up_thread = threading.Thread(
            target=self._run_warm_up, name="warm-up", daemon=True
        )
        self._warm_up_thread.start()

    def _run_warm_up(self) -> None:
        def done(timing: GroupTiming) -> None:
            with self._compiled_groups:
                self._compiled_names.add(timing.name)
                self._compiled_groups.notify_all()

        report = warm_up(
            self.config.model,
            progress=lambda line: print(line, file=sys.stderr, flush=True),
            on_done=done,
        )
        with self._compiled_groups:
            self.warm_up_report = report
            self._compiled_groups.notify_all()
        if not report.cached:
            self.say(f"kernels compiled in {report.seconds:.1f} s (first run on this machine only)")
            for group in report.groups:
                if not group.ok:
                    self.say(f"warning: {group.name} did not compile ahead: {group.error}")

    def _wait_for_kernels(self, process: str) -> bool:
        """Wait until the kernel groups ``process`` runs are compiled; False if stopped."""
        needed = {g.name for g in KERNEL_GROUPS if process in g.processes}
        with self._compiled_groups:
            while self.warm_up_report is None and not needed <= self._compiled_names:
                if self.stop.is_set():
                    self.failure = "interrupted while compiling"
                    return False
                self._compiled_groups.wait(0.1)
        return True

    def _wait_for_first_estimate(self) -> bool:
        """Wait for the service's first estimate; the run (and ``--duration``) starts there."""
        self.say("waiting for the first estimate")
        deadline = time.perf_counter() + self.config.startup_timeout_s
        while (first := self.monitor.first_estimate()) is None:
            dead = [c for c in self.children if c.name != "dashboard" and not c.running()]
            if self.stop.is_set():
                self.failure = "interrupted before the first estimate"
                return False
            if dead or time.perf_counter() > deadline:
                self.failure = (
                    f"{dead[0].name} exited before the first estimate; see {self.log_path}"
                    if dead
                    else f"no estimate within {self.config.startup_timeout_s:g} s of start-up: "
                    f"the service is silent; see {self.log_path}"
                )
                self.say(self.failure)
                return False
            time.sleep(0.01)
        self.first_estimate_s = (first[0] - self._start_wall_ns) * 1e-9
        self._mark_running()
        until = "Ctrl-C" if self.config.duration_s is None else f"{self.config.duration_s:g} s"
        self.say(
            f"first estimate {self.first_estimate_s:.1f} s after the command "
            f"(source seq {first[1]}); running until {until} (or Ctrl-C)"
        )
        return True

    def _mark_running(self) -> None:
        """Start the run's clock and its CPU and load baselines."""
        # Full collections of everything imported would stall the monitor for tens of ms.
        gc.collect()
        gc.freeze()
        self.running_s = time.perf_counter()
        self._cpu_at_run = {c.name: c.cpu_s() for c in self.children}
        own = os.times()
        self._own_cpu_at_run = own.user + own.system
        self._load_at_run = list(os.getloadavg())
        self._scheduling = {c.name: c.scheduling() for c in self.children}

    def _connect_args(self) -> list[str]:
        return ["--connect", self.endpoint, "--listen", _ANY_LOOPBACK_PORT, "--no-multicast"]

    def _start_recorder(self, log: IO[bytes]) -> Child:
        """Start the session recorder (the slave waits for it: it records from the first sample).

        Recording runs in a process of its own, off the service's 1 kHz path
        (:mod:`teleop_force.service.session_recorder`).
        """
        config = self.config
        args = [
            "--record", str(self.recording), "--device", config.slave, "--master", config.master,
            "--model", str(config.model or DEFAULT_MODEL_PATH),
            "--monitor", "--contact-threshold", repr(config.accuracy.contact_threshold_n),
        ]  # fmt: skip
        argv = _python_module("teleop_force.service.session_recorder", *args, *self._connect_args())
        child = Child("recorder", argv, log, nice=config.realtime_nice)
        self.children.append(child)
        self.say(f"started recorder (pid {child.pid})")
        return child

    def _start_router(self, log: IO[bytes]) -> None:
        """Start the router on the rendezvous endpoint; wait until it accepts connections."""
        argv = _python_module("teleop_force.transport.router", "--listen", self.endpoint)
        # the network between the processes: as urgent as the loops it carries
        priority = self.config.rt_priority + 1 if self.config.rt_priority else 0
        child = Child("router", argv, log, nice=self.config.realtime_nice, rt_priority=priority)
        self.children.append(child)
        self.say(f"started router (pid {child.pid}) on {self.endpoint}")
        deadline = time.perf_counter() + self.config.startup_timeout_s
        while time.perf_counter() < deadline and child.running():
            if _accepts_connections(self.endpoint):
                return
            time.sleep(0.05)
        child.stop()
        raise TransportError(f"the router did not come up on {self.endpoint}; see {self.log_path}")

    def _start_all(self, log: IO[bytes]) -> bool:
        config = self.config
        self.started_s = time.perf_counter()
        service = ["--device", config.slave, "--master", config.master]
        if config.model is not None:
            service += ["--model", str(config.model)]
        started: list[tuple[Child, str]] = []
        if config.record:  # waited for before the slave starts: it records the first sample
            started.append((self._start_recorder(log), keys.alive(config.slave, "recorder")))
        service += list(config.service_args)
        wait = str(config.startup_timeout_s)
        surface = str(config.surface_y_m)
        master = [
            "--device", config.master, "--slave", config.slave, "--motion", config.motion,
            "--surface-y", surface, "--wait-subscribers", wait, *config.master_args,
        ]  # fmt: skip
        if config.haptic_feedback:
            master.append("--haptic-feedback")
        slave = [
            "--device", config.slave, "--master", config.master,
            "--surface-y", surface, "--wait-subscribers", wait, *config.slave_args,
        ]  # fmt: skip
        steps = [
            (
                "service",
                "teleop_force.service.force_service",
                service,
                keys.alive(config.slave, "service"),
            ),
            ("slave", "master_slave.slave", slave, keys.alive(config.slave, "slave")),
            ("master", "master_slave.master", master, keys.alive(config.master, "master")),
        ]
        # Started together (their imports overlap); the order of the data flow is kept by the
        # handshakes: the slave streams once something subscribes to its joint states, the
        # master once the slave subscribes to its setpoints. With a recorder (a subscriber of
        # every joint state too), the slave starts only once the service is up, so that the
        # service sees the stream from its first sample.
        for name, module, args, token in steps:
            if name == "slave" and config.record:
                for child, waited in started:
                    if not self._wait_for_token(child, waited):
                        return False
            if not self._wait_for_kernels(name):
                return False
            argv = _python_module(module, *args, *self._connect_args())
            # the loops (short bursts, hard deadlines) preempt the service's estimation
            priority = config.rt_priority + (name != "service") if config.rt_priority else 0
            child = Child(name, argv, log, nice=config.realtime_nice, rt_priority=priority)
            self.children.append(child)
            started.append((child, token))
            self.say(f"started {name} (pid {child.pid})")
        for child, token in started:
            if not self._wait_for_token(child, token):
                return False
        self._start_dashboard(log)
        startup = time.perf_counter() - self.started_s
        self.say(f"all processes up in {startup:.1f} s")
        return True

    def _start_dashboard(self, log: IO[bytes]) -> None:
        config = self.config
        url = f"http://127.0.0.1:{config.dashboard_port}/"
        if config.headless:
            self.say("dashboard: not started (--headless)")
            return
        if not dashboard_available():
            self.say("dashboard: not started: web/__main__.py does not exist yet")
            return
        if not self._wait_for_kernels("dashboard"):
            return
        args = [
            "--device", config.slave, "--port", str(config.dashboard_port),
            "--connect", self.endpoint,
            "--master-device", config.master, "--tissue-y", str(config.surface_y_m),
        ]  # fmt: skip
        child = Child("dashboard", _python_module("web", *args), log)
        self.children.append(child)
        self.say(f"started dashboard (pid {child.pid})")
        self.say(f"dashboard: {url}")

    def _wait_for_token(self, child: Child, token: str) -> bool:
        deadline = time.perf_counter() + self.config.startup_timeout_s
        self._tokens[child.name] = token
        while not self.presence.has(token):
            if self.stop.is_set():
                self.failure = "interrupted during start-up"
                return False
            if not child.running():
                code = child.process.returncode
                self.failure = (
                    f"{child.name} exited during start-up (code {code}); see {self.log_path}"
                )
                self.say(self.failure)
                return False
            if time.perf_counter() > deadline:
                self.failure = (
                    f"{child.name} did not come up within {self.config.startup_timeout_s:g} s"
                )
                self.say(self.failure)
                return False
            time.sleep(0.02)
        return True

    def _up_after_s(self) -> dict[str, float | None]:
        """Seconds from this process's start to each waited-for child's token (None: never)."""
        seen = self.presence.first_seen_ns
        return {
            name: None
            if token not in seen
            else round((seen[token] - self._start_wall_ns) * 1e-9, 3)
            for name, token in self._tokens.items()
        }

    def _watch(self) -> None:
        config = self.config
        end = None if config.duration_s is None else self.running_s + config.duration_s
        next_report = self.running_s + (config.report_period_s or math.inf)
        while not self.stop.is_set():
            now = time.perf_counter()
            if end is not None and now >= end:
                break
            dead = [c for c in self.children if c.name != "dashboard" and not c.running()]
            if dead:
                code = dead[0].process.returncode
                self.failure = (
                    f"{dead[0].name} exited unexpectedly (code {code}); see {self.log_path}"
                )
                self.say(self.failure)
                break
            if now >= next_report:
                self._report(now - self.running_s)
                next_report += config.report_period_s
            wake = min(next_report, end if end is not None else math.inf)
            self.stop.wait(max(0.0, min(0.2, wake - time.perf_counter())))

    def _query(self, key: str, timeout_s: float = 1.0) -> dict[str, Any] | None:
        assert self.session is not None
        try:
            value = query_json(self.session, key, timeout_s)
        except TransportError:
            return None
        return value if isinstance(value, dict) else None

    def _report(self, elapsed_s: float) -> None:
        config = self.config
        service = self._query(keys.service_stats(config.slave), 0.5)
        slave = self._query(keys.process_stats(config.slave, "slave"), 0.5)
        figures = self.monitor.figures() or {}
        js = (service or {}).get("joint_states", {})
        lost = self._lost(service, slave, figures)["total"]
        relative = None
        if int(elapsed_s) % 5 == 0:
            relative = (figures.get("force_error") or {}).get("relative_rms_error")
        line = (
            f"t={elapsed_s:5.1f}s  F_est={_fmt_force(figures.get('latest_estimate_n'))}  "
            f"F_true={_fmt_force(figures.get('latest_true_n'))} N  "
            f"js {js.get('rate_hz', 0):6.1f} Hz  lost {lost}  "
            f"lat m->s {_ms((slave or {}).get('setpoints', {}).get('latency_ms'), 'p50')}/"
            f"{_ms((slave or {}).get('setpoints', {}).get('latency_ms'), 'p99')} ms  "
            f"s->est {_ms((service or {}).get('latency_ms'), 'p50')}/"
            f"{_ms((service or {}).get('latency_ms'), 'p99')} ms  "
            f"{figures.get('state', 'unknown')}"
        )
        if relative is not None:
            line += f"  rms err (contact) {relative:.1%}"
        self.say(line)

    def _lost(
        self,
        service: dict[str, Any] | None,
        slave: dict[str, Any] | None,
        figures: dict[str, Any] | None,
    ) -> dict[str, int]:
        parts = {
            "setpoints_at_slave": int((slave or {}).get("setpoints", {}).get("lost", 0)),
            "joint_states_at_service": int((service or {}).get("joint_states", {}).get("lost", 0)),
            "joint_states_dropped_by_service": int(
                (service or {}).get("joint_states", {}).get("overflow_dropped", 0)
            ),
            "estimates_at_supervisor": int(((figures or {}).get("estimates") or {}).get("lost", 0)),
            "true_forces_at_supervisor": int(
                ((figures or {}).get("true_forces") or {}).get("lost", 0)
            ),
            "dropped_by_recorder": int(
                ((self._recorder_stats or {}).get("recorder") or {}).get("dropped", 0)
            ),
        }
        parts["total"] = sum(parts.values())
        return parts

    def _final_stats(self) -> dict[str, Any]:
        config = self.config
        wall = time.perf_counter() - self.running_s if self.running_s else 0.0
        for child in self.children:
            now, then = child.cpu_s(), self._cpu_at_run.get(child.name)
            percent = None
            if now is not None and then is not None and wall > 0.0:
                percent = round(100.0 * (now - then) / wall, 1)
            self.cpu_percent[child.name] = percent
        if wall > 0.0:
            own = os.times()
            used = own.user + own.system - self._own_cpu_at_run
            self.cpu_percent["supervisor"] = round(100.0 * used / wall, 1)
            known = [v for v in self.cpu_percent.values() if v is not None]
            self.cpu_percent["total"] = round(sum(known), 1) if known else None
        return {
            "service": self._query(keys.service_stats(config.slave), 2.0),
            "slave": self._query(keys.process_stats(config.slave, "slave"), 2.0),
            "master": self._query(keys.process_stats(config.master, "master"), 2.0),
            "recorder": (
                self._query(keys.process_stats(config.slave, "recorder"), 2.0)
                if config.record
                else None
            ),
            "monitor": self.monitor.figures(final=True),
        }

    def _stop_children(self) -> None:
        order = {"master": 0, "dashboard": 1, "slave": 2, "service": 3, "recorder": 4}
        for child in sorted(self.children, key=lambda c: order.get(c.name, 9)):
            was_running = child.running()
            code = child.stop()
            if was_running and code not in (0, -signal.SIGTERM, None):
                self.say(f"{child.name} exited with code {code}")

    # -- summary --------------------------------------------------------------------------------

    def _summary(self, final: dict[str, Any]) -> dict[str, Any]:
        service, slave, master = final.get("service"), final.get("slave"), final.get("master")
        self._recorder_stats = final.get("recorder")
        figures = final.get("monitor") or self.monitor.figures(final=True) or {}
        lost = self._lost(service, slave, figures)
        setpoint_latency = (slave or {}).get("setpoints", {}).get("latency_ms") or {}
        estimate_latency = (service or {}).get("latency_ms") or {}
        accuracy = figures.get("force_error") or ForceAccuracy(self.config.accuracy).summary()
        running = self.ended_s - self.running_s if self.running_s else 0.0
        coverage = _estimate_coverage(service, slave)
        return {
            "ok": not self.failure,
            "failure": self.failure,
            "duration_s": round(running, 3),
            "first_estimate_s": (
                None if self.first_estimate_s is None else round(self.first_estimate_s, 3)
            ),
            "up_after_s": self._up_after_s(),
            "warm_up": None if self.warm_up_report is None else self.warm_up_report.summary(),
            "estimate_coverage": coverage,
            "recording": str(self.recording),
            "log": str(self.log_path),
            "zenoh_endpoint": self.endpoint,
            "pids": {c.name: c.pid for c in self.children},
            "scheduling": self._scheduling,
            "messages_lost": lost,
            "master_to_slave_latency_ms": {
                "p50": setpoint_latency.get("p50"),
                "p99": setpoint_latency.get("p99"),
                "max": setpoint_latency.get("max"),
                "count": setpoint_latency.get("count"),
            },
            "slave_to_estimate_latency_ms": {
                "p50": estimate_latency.get("p50"),
                "p99": estimate_latency.get("p99"),
                "max": estimate_latency.get("max"),
                "count": estimate_latency.get("count"),
            },
            "force_error": accuracy,
            "rates_hz": {
                "joint_states_at_service": (service or {})
                .get("joint_states", {})
                .get("mean_rate_hz"),
                "slave_loop": (slave or {}).get("loop", {}).get("rate_hz"),
                "master_loop": (master or {}).get("loop", {}).get("rate_hz"),
            },
            "loop_overruns": {
                "slave": (slave or {}).get("loop", {}).get("overruns"),
                "master": (master or {}).get("loop", {}).get("overruns"),
            },
            "loop_overrun_fraction": {
                "slave": (slave or {}).get("loop", {}).get("overrun_fraction"),
                "master": (master or {}).get("loop", {}).get("overrun_fraction"),
            },
            "loops": {"slave": _loop_summary(slave), "master": _loop_summary(master)},
            "malformed_dropped": {
                "service": (service or {}).get("malformed", {}).get("dropped"),
                "slave": (slave or {}).get("setpoints", {}).get("malformed"),
                "supervisor": figures.get("malformed"),
            },
            "slave_holds": (slave or {}).get("holds"),
            "cpu_percent": self.cpu_percent,
            "cpu_percent_of_one_core": self.cpu_percent,
            "machine_load_average": list(os.getloadavg()),
            "machine_load_average_at_start": self._load_at_run,
            "stats": final,
        }

    def _print_summary(self, summary: dict[str, Any]) -> None:
        def ms(part: dict[str, Any]) -> str:
            p50, p99 = part.get("p50"), part.get("p99")
            if p50 is None or p99 is None:
                return "n/a"
            return f"p50 {p50:.3f} ms, p99 {p99:.3f} ms"

        force = summary["force_error"]
        lost = summary["messages_lost"]
        relative = force.get("relative_rms_error")
        lagfree = force.get("relative_rms_error_vs_filtered_true")
        self.say("")
        self.say("== demo summary ==")
        if summary["failure"]:
            self.say(f"FAILED: {summary['failure']}")
        self.say(f"duration: {summary['duration_s']:.1f} s   recording: {summary['recording']}")
        first = summary["first_estimate_s"]
        up = ", ".join(
            f"{name} {'never' if t is None else f'{t:.1f} s'}"
            for name, t in summary["up_after_s"].items()
        )
        self.say(
            f"first estimate: {'none' if first is None else f'{first:.1f} s'} after the "
            f"command; up after: {up}"
        )
        for line in _coverage_lines(summary["estimate_coverage"]):
            self.say(line)
        self.say(
            f"messages lost: {lost['total']} (setpoints at slave {lost['setpoints_at_slave']}, "
            f"joint states at service {lost['joint_states_at_service']}, estimates "
            f"{lost['estimates_at_supervisor']}, true forces {lost['true_forces_at_supervisor']})"
        )
        to_slave = ms(summary["master_to_slave_latency_ms"])
        to_estimate = ms(summary["slave_to_estimate_latency_ms"])
        self.say(f"master->slave latency (setpoint stamp -> slave receipt): {to_slave}")
        self.say(f"slave->estimate latency (joint-state stamp -> estimate): {to_estimate}")
        if relative is None:
            self.say("force estimate RMS error during contact: n/a (no contact)")
        else:
            self.say(
                f"force estimate RMS error during contact: {force['rms_error_n']:.3f} N = "
                f"{relative:.1%} of the RMS true force {force['rms_true_n']:.3f} N "
                f"({force['contact_samples']} samples with "
                f"|F| > {force['contact_threshold_n']:g} N; "
                f"{lagfree:.1%} against the true force low-passed like the estimate)"
            )
        for name, loop in summary["loops"].items():
            self.say(f"{name} loop: {_fmt_loop(loop)}")
        self.say(f"slave holds: {summary['slave_holds']}")
        cpu = ", ".join(f"{k} {v:.0f}%" for k, v in summary["cpu_percent"].items() if v is not None)
        load = ", ".join(f"{x:.1f}" for x in summary["machine_load_average"])
        self.say(f"CPU while running (% of one core): {cpu}; machine load average {load}")


def _estimate_coverage(
    service: dict[str, Any] | None, slave: dict[str, Any] | None
) -> dict[str, Any]:
    """Joint states the slave sent, the service received and estimated, and the fraction."""
    sent = (slave or {}).get("published_joint_states")
    joint_states = (service or {}).get("joint_states") or {}
    estimates = (service or {}).get("estimates") or {}
    estimated = estimates.get("published")
    fraction = None
    if isinstance(sent, int) and isinstance(estimated, int) and sent > 0:
        fraction = round(estimated / sent, 6)
    return {
        "sent_by_slave": sent,
        "received_by_service": joint_states.get("received"),
        "lost_on_the_way": joint_states.get("lost"),
        "dropped_by_service": joint_states.get("overflow_dropped"),
        "estimation_errors": estimates.get("errors"),
        "estimated": estimated,
        "estimated_fraction": fraction,
    }


#: Below this share of the slave's joint states estimated, the summary says so plainly.
ESTIMATED_FRACTION_EXPECTED: Final = 0.99


def _coverage_lines(coverage: dict[str, Any]) -> list[str]:
    """Return the summary's lines on the estimates against the joint states the slave sent."""
    sent, estimated = coverage["sent_by_slave"], coverage["estimated"]
    if sent is None:
        return ["estimates: unknown: the slave's statistics did not arrive (silent or gone)"]
    if estimated is None:
        return [f"estimates: unknown of {sent} joint states: the service's statistics did not "
                "arrive (silent or gone)"]  # fmt: skip
    fraction = coverage["estimated_fraction"]
    line = f"estimates: {estimated} of the {sent} joint states the slave sent"
    if fraction is None:
        return [line]
    line += f" ({fraction:.2%})"
    if fraction >= ESTIMATED_FRACTION_EXPECTED:
        return [line]
    why = [
        f"{coverage[k]} {label}"
        for k, label in (
            ("lost_on_the_way", "lost on the way"),
            ("dropped_by_service", "dropped by the service"),
            ("estimation_errors", "refused by the estimator"),
        )
        if coverage.get(k)
    ]
    received = coverage["received_by_service"]
    if isinstance(received, int) and received < sent:
        why.append(f"{sent - received} never reached the service")
    return [
        f"WARNING: the service estimated only {fraction:.1%} of the joint states the slave "
        f"sent ({'; '.join(why) or 'no counter says why'})"
    ]


def run_demo(config: DemoConfig, stop: StopSignal | None = None) -> dict[str, Any]:
    """Run the demo (see the module docstring); return the summary."""
    stop = stop if stop is not None else StopSignal()
    return DemoSupervisor(config, stop).run()


__all__ = [
    "DEFAULT_DASHBOARD_PORT",
    "Child",
    "DemoConfig",
    "DemoSupervisor",
    "dashboard_available",
    "run_demo",
]
