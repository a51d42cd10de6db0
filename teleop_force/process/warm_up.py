"""Compile the live processes' kernels ahead of time, in parallel, into numba's on-disk cache.

A process of the live system compiles (on a machine without a cache) or loads its kernels
before it declares itself up (:func:`compile_group`); compiling them all in one process
takes most of a minute. :func:`warm_up` compiles the groups of :data:`KERNEL_GROUPS` in
parallel child processes (one per core), each into numba's cache, and reports progress; the
processes started afterwards only load them. A stamp in the cache records what was compiled
for which sources, numba and CPU: when it matches, nothing is started.

``python -m teleop_force.process.warm_up [--jobs N] [--model MODEL]`` runs it by hand (CI
runs it before the tests); ``--group NAME`` compiles one group in this process.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.metadata
import json
import os
import platform
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from teleop_force.errors import ConfigurationError, TeleopForceError

_PACKAGE_ROOT: Final = Path(__file__).resolve().parents[1]
_STAMP_NAME: Final = "teleop_force_warm_up.json"
_MODULE: Final = "teleop_force.process.warm_up"


@dataclass(frozen=True)
class KernelGroup:
    """Kernels one process needs, compiled together.

    Attributes:
        name: Short name (``--group``).
        label: What it is, for progress lines ("the estimator's step").
        target: ``module:function`` that compiles the group, called with the model path
            (``None``: the shipped model).
        processes: The demo's processes that run these kernels (they start once it is done).

    """

    name: str
    label: str
    target: str
    processes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        """Check the target's form."""
        module, _, function = self.target.partition(":")
        if not module or not function:
            raise ConfigurationError(f"a kernel group's target is module:function: {self.target}")

    def compile(self, model_path: Path | None) -> None:
        """Import the target and run it in this process."""
        module, _, function = self.target.partition(":")
        target: Callable[[Path | None], None] = getattr(
            __import__(module, fromlist=[function]), function
        )
        target(model_path)


#: The groups, largest first (the order they are started in).
KERNEL_GROUPS: Final = (
    KernelGroup(
        "estimator-step", "the estimator's step", "teleop_force.service.kernels:compile_step",
        ("service",),
    ),
    KernelGroup(
        "count-observer", "the count observer", "teleop_force.service.kernels:compile_observer",
        ("service",),
    ),
    KernelGroup(
        "residual-watch", "the residual watch's estimator",
        "teleop_force.service.kernels:compile_watch", ("service",),
    ),
    KernelGroup(
        "plants", "the master's and slave's plants", "master_slave.slave:compile_plant_kernels",
        ("slave", "master"),
    ),
    KernelGroup(
        "dashboard", "the dashboard's coverage map", "web.coverage_data:compile_kernels",
        ("dashboard",),
    ),
)  # fmt: skip


@dataclass(frozen=True)
class GroupTiming:
    """One group's compilation: wall time of its child process [s] and whether it worked."""

    name: str
    seconds: float
    ok: bool
    error: str = ""


@dataclass(frozen=True)
class WarmUpReport:
    """What :func:`warm_up` did: ``cached`` (nothing to do) or the groups' timings."""

    cached: bool
    seconds: float
    groups: tuple[GroupTiming, ...] = ()

    @property
    def ok(self) -> bool:
        """Whether every group compiled."""
        return all(g.ok for g in self.groups)

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures (``bench --json``, the demo's summary)."""
        return {
            "cached": self.cached,
            "seconds": round(self.seconds, 3),
            "groups": {g.name: {"seconds": round(g.seconds, 3), "ok": g.ok} for g in self.groups},
        }


def cache_dir() -> Path:
    """Where numba caches this package's kernels (``$NUMBA_CACHE_DIR``, or beside the modules)."""
    configured = os.environ.get("NUMBA_CACHE_DIR", "")
    return Path(configured) if configured else _PACKAGE_ROOT / "__pycache__"


def _target_cpu() -> str:
    """Return the CPU numba compiles for: ``$NUMBA_CPU_NAME`` or the host's, with features."""
    import llvmlite.binding as llvm

    name = os.environ.get("NUMBA_CPU_NAME") or llvm.get_host_cpu_name()
    features = os.environ.get("NUMBA_CPU_FEATURES") or llvm.get_host_cpu_features().flatten()
    return f"{name}:{features}"


def sources_key(model_path: Path | None) -> str:
    """Hash of what the cached code depends on: sources, model file, numba, Python, CPU."""
    digest = hashlib.sha256()
    roots = [_PACKAGE_ROOT, _PACKAGE_ROOT.parent / "master_slave"]
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            stat = path.stat()
            digest.update(f"{path}:{stat.st_mtime_ns}:{stat.st_size}\n".encode())
    if model_path is not None:
        digest.update(Path(model_path).read_bytes())
    numba_version = importlib.metadata.version("numba")
    for part in (numba_version, platform.python_version(), _target_cpu()):
        digest.update(part.encode())
    digest.update(os.environ.get("NUMBA_OPT", "").encode())
    return digest.hexdigest()


def _stamp_path() -> Path:
    return cache_dir() / _STAMP_NAME


def is_warm(model_path: Path | None = None) -> bool:
    """Whether the stamp says every group is compiled for today's sources and CPU."""
    try:
        stamp = json.loads(_stamp_path().read_text())
    except (OSError, ValueError):
        return False
    return isinstance(stamp, dict) and stamp.get("key") == sources_key(model_path)


def _write_stamp(model_path: Path | None) -> None:
    path = _stamp_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"key": sources_key(model_path)}))
    except OSError:
        pass  # a read-only place: the next run checks again, which costs only its time


def warm_up(
    model_path: Path | None = None,
    *,
    jobs: int | None = None,
    progress: Callable[[str], None] | None = None,
    force: bool = False,
    on_done: Callable[[GroupTiming], None] | None = None,
) -> WarmUpReport:
    """Compile every group in parallel child processes unless the stamp says they are cached.

    ``jobs``: processes at once (default: the CPUs this process may run on). ``progress`` is
    called with one line per group started and finished ("compiling the estimator's step,
    first run only (1/5)"), ``on_done`` with each group's timing as it ends (from a worker
    thread). A group that fails is reported, not raised: the process that needs it then
    compiles it itself.
    """
    started = time.perf_counter()
    if not force and is_warm(model_path):
        return WarmUpReport(cached=True, seconds=time.perf_counter() - started)
    say = progress or (lambda line: None)
    jobs = max(1, jobs if jobs is not None else len(os.sched_getaffinity(0)))
    total = len(KERNEL_GROUPS)
    lock = threading.Lock()
    counts = {"started": 0, "done": 0}

    def run(group: KernelGroup) -> GroupTiming:
        with lock:
            counts["started"] += 1
            say(f"compiling {group.label}, first run only ({counts['started']}/{total})")
        argv = [sys.executable, "-m", _MODULE, "--group", group.name]
        if model_path is not None:
            argv += ["--model", str(model_path)]
        t0 = time.perf_counter()
        # run to the end of its output (the pipes close when the process exits), then reaped
        process = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        seconds = time.perf_counter() - t0
        ok = process.returncode == 0
        lines = process.stderr.decode(errors="replace").strip().splitlines()
        timing = GroupTiming(group.name, seconds, ok, "" if ok else (lines or ["no output"])[-1])
        with lock:
            counts["done"] += 1
            outcome = "compiled" if ok else f"failed ({timing.error}); its process will compile it"
            say(f"{group.label}: {outcome} in {seconds:.1f} s ({counts['done']}/{total})")
        if on_done is not None:
            on_done(timing)
        return timing

    with ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="warm-up") as pool:
        timings = tuple(pool.map(run, KERNEL_GROUPS))  # started in order: the largest first
    report = WarmUpReport(cached=False, seconds=time.perf_counter() - started, groups=timings)
    if report.ok:
        _write_stamp(model_path)
    return report


def compile_group(name: str, model_path: Path | None = None) -> None:
    """Compile (or load) one group in this process; ConfigurationError for an unknown name."""
    for group in KERNEL_GROUPS:
        if group.name == name:
            group.compile(model_path)
            return
    names = ", ".join(g.name for g in KERNEL_GROUPS)
    raise ConfigurationError(f"no kernel group {name!r} (groups: {names})")


def main(argv: Sequence[str] | None = None) -> int:
    """Warm the cache (or compile ``--group``); print the report as JSON with ``--json``."""
    parser = argparse.ArgumentParser(prog="python -m teleop_force.process.warm_up")
    parser.add_argument("--group", default=None, help="compile this group here and exit")
    parser.add_argument("--model", type=Path, default=None, help="model file (default: shipped)")
    parser.add_argument("--jobs", type=int, default=None, help="processes at once")
    parser.add_argument("--force", action="store_true", help="compile even if the stamp matches")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    args = parser.parse_args(argv)
    try:
        if args.group is not None:
            compile_group(args.group, args.model)
            return 0
        report = warm_up(
            args.model,
            jobs=args.jobs,
            force=args.force,
            progress=lambda line: print(line, file=sys.stderr, flush=True),
        )
    except TeleopForceError as exc:
        print(f"warm_up: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report.summary()))
    elif report.cached:
        print("compiled kernels: cached", file=sys.stderr)
    return 0 if report.ok else 1


if __name__ == "__main__":
    sys.exit(main())
