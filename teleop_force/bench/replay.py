"""Figures 4-5 of ``teleop-force bench``: replay through the service, and its peak memory.

A worker process (``python -m teleop_force.bench.replay --job SESSION MODEL ...``) does what
``teleop-force replay SESSION --fast --with-service --model MODEL`` does, in one process on an
isolated Zenoh session (no multicast scouting, loopback): a
:class:`~teleop_force.service.force_service.ForceService` subscribes to the device's joint states
and the
session's messages are published as fast as possible
(:func:`~teleop_force.io.replay.replay_session` with ``speed=0``). The clock runs from the
replay's start (opening the session file included) until the service has estimated on every
replayed joint state; throughput is the recorded span over that wall time (the service
estimates in its own worker thread, so publishing may finish first: ``publish_wall_s`` is
the publishing alone). The worker's ``VmHWM`` (peak resident set) is read after each job:
run one job per worker for isolated memory figures.

The worker prints one JSON list (a dict per job) on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from teleop_force.bench.measure import stopwatch
from teleop_force.process.memory import peak_rss_mb, resident_memory_mb

if TYPE_CHECKING:
    from teleop_force.service.force_service import ForceService

#: Longest wait for the service to catch up after the last publication [s].
_CATCH_UP_S = 120.0


def _handled(service: ForceService) -> int:
    """Joint states the service is done with: estimated and published, or failed."""
    return service.estimates.published + service.estimates.errors


def replay_job(session_path: Path, model_path: Path) -> dict[str, Any]:
    """Replay one session through an in-process service; return the figures."""
    from teleop_force.io.mcap_session import MEASURED_JS, SessionReader
    from teleop_force.io.replay import ReplayConfig, primary_device, replay_session
    from teleop_force.process.lifetime import StopSignal
    from teleop_force.service.force_service import ForceService, ServiceConfig, load_model
    from teleop_force.transport.session import ZenohOptions, open_session

    reader = SessionReader(session_path)
    device = primary_device(reader)
    expected = reader.stream_count(device, MEASURED_JS)
    model, _ = load_model(model_path)
    session = open_session(ZenohOptions(mode="peer", multicast_scouting=False))
    rss_before = resident_memory_mb() or 0.0
    service = ForceService(session, model, ServiceConfig(device=device, source="replay"))
    try:
        service.start()
        config = ReplayConfig(session_path, speed=0.0, device=device, wait_subscribers_s=10.0)
        with stopwatch() as watch:
            result = replay_session(session, config, StopSignal())
            deadline = time.perf_counter() + _CATCH_UP_S
            while _handled(service) < expected and time.perf_counter() < deadline:
                time.sleep(0.001)
        stats = service.stats()
    finally:
        service.close()
        session.close()
    span = result.recorded_span_s
    return {
        "session": str(session_path),
        "model": str(model_path),
        "recorded_span_s": span,
        "wall_s": round(watch.wall_s, 4),
        "cpu_s": round(watch.cpu_s, 4),
        "publish_wall_s": result.duration_s,
        "x_realtime": round(span / watch.wall_s, 3) if watch.wall_s > 0 else None,
        "messages_published": sum(result.published.values()),
        "joint_states_expected": expected,
        "joint_states_received": stats["joint_states"]["received"],
        "joint_states_lost": stats["joint_states"]["lost"],
        "joint_states_dropped": stats["joint_states"].get("overflow_dropped", 0),
        "estimates_published": stats["estimates"]["published"],
        "estimate_errors": stats["estimates"]["errors"],
        "processing_ms": stats.get("processing_ms"),
        "rss_before_replay_mb": round(rss_before, 2),
        "peak_rss_mb": round(peak_rss_mb() or 0.0, 2),
    }


def run_workers(
    jobs: Sequence[tuple[Path, Path]], isolated: bool = True, timeout_s: float = 900.0
) -> list[dict[str, Any]]:
    """Run ``jobs`` (session, model) in worker processes: one per job if ``isolated``."""
    groups = [[job] for job in jobs] if isolated else [list(jobs)]
    results: list[dict[str, Any]] = []
    for group in groups:
        argv = [sys.executable, "-m", "teleop_force.bench.replay"]
        for session_path, model_path in group:
            argv += ["--job", str(session_path), str(model_path)]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        proc = subprocess.run(
            argv, capture_output=True, text=True, timeout=timeout_s, env=env, check=False
        )
        if proc.returncode != 0:
            tail = proc.stderr.strip().splitlines()[-5:]
            raise RuntimeError(f"replay worker failed ({proc.returncode}): {' | '.join(tail)}")
        results += json.loads(proc.stdout)
    return results


def main(argv: Sequence[str] | None = None) -> int:
    """Worker entry point: run the jobs, print their figures as one JSON list."""
    parser = argparse.ArgumentParser(prog="python -m teleop_force.bench.replay")
    parser.add_argument(
        "--job", nargs=2, action="append", metavar=("SESSION", "MODEL"), required=True
    )
    args = parser.parse_args(argv)
    out = [replay_job(Path(s), Path(model)) for s, model in args.job]
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
