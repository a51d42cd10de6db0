"""Figure 3 of ``teleop-force bench``: messaging latency and loss, from the headless demo.

Runs ``teleop-force demo --headless --duration S --summary-json PATH`` as a subprocess (its
own master, slave and service processes on loopback Zenoh at 1 kHz) and reads the summary:
master -> slave latency (setpoint stamp -> slave receipt), slave -> estimate latency
(joint-state stamp -> estimate published) and messages lost. While it runs, the service
process's ``VmHWM`` (peak resident set) is polled from ``/proc``: the figure kept is the
last value read before it exits.

``latency_end_to_end_p99_ms`` is the sum of the two p99s: an upper bound of the p99 of a
setpoint's way to the estimate (the demo does not pair setpoints with estimates).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from teleop_force.bench.measure import command_line, descendants
from teleop_force.process.memory import peak_rss_mb

#: Poll period of the service's memory [s].
_POLL_S = 0.25


def _service_pid(demo_pid: int) -> int | None:
    for pid in descendants(demo_pid):
        if "teleop_force.service.force_service" in command_line(pid):
            return pid
    return None


def run_demo(
    duration_s: float,
    model_path: Path | None = None,
    startup_timeout_s: float = 180.0,
    extra_args: tuple[str, ...] = (),
    env: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Run the headless demo for ``duration_s``; return its summary plus the service's peak RSS.

    Keys added to the summary: ``service_peak_rss_mb`` (``None`` if it could not be read),
    ``bench_wall_s``. ``env``: variables set for the demo on top of this process's. Raises
    RuntimeError if the demo fails.
    """
    with tempfile.TemporaryDirectory(prefix="teleop-bench-demo-") as tmp:
        summary_path = Path(tmp) / "summary.json"
        argv = [
            sys.executable, "-m", "teleop_force.cli.main", "demo", "--headless",
            "--duration", f"{duration_s:g}", "--record-dir", tmp,
            "--summary-json", str(summary_path),
        ]  # fmt: skip
        if model_path is not None:
            argv += ["--model", str(model_path)]
        argv += list(extra_args)
        started = time.perf_counter()
        log_path = Path(tmp) / "demo-stdout.txt"
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(
                argv, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
            )
            peak: float | None = None
            service: int | None = None
            deadline = started + startup_timeout_s + duration_s + 60.0
            try:
                while proc.poll() is None:
                    if time.perf_counter() > deadline:
                        proc.terminate()
                        proc.wait(30)
                        raise RuntimeError("the demo did not finish in time")
                    if service is None:
                        service = _service_pid(proc.pid)
                    if service is not None:
                        value = peak_rss_mb(service)
                        if value is not None:
                            peak = value
                    time.sleep(_POLL_S)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        if proc.returncode != 0 or not summary_path.exists():
            tail = log_path.read_text(errors="replace").strip().splitlines()[-5:]
            raise RuntimeError(f"demo failed ({proc.returncode}): {' | '.join(tail)}")
        summary: dict[str, Any] = json.loads(summary_path.read_text())
    summary["service_peak_rss_mb"] = None if peak is None else round(peak, 2)
    summary["bench_wall_s"] = round(time.perf_counter() - started, 2)
    return summary


def messaging_figures(summary: dict[str, Any]) -> dict[str, Any]:
    """Return the JSON figures of a demo summary (keys carry their units)."""
    to_slave = summary.get("master_to_slave_latency_ms") or {}
    to_estimate = summary.get("slave_to_estimate_latency_ms") or {}
    lost = summary.get("messages_lost") or {}
    p99s = [to_slave.get("p99"), to_estimate.get("p99")]
    service = (summary.get("stats") or {}).get("service") or {}
    processing = service.get("processing_ms") or {}
    return {
        "messaging_duration_s": summary.get("duration_s"),
        "messaging_ok": bool(summary.get("ok")),
        "latency_master_to_slave_p50_ms": to_slave.get("p50"),
        "latency_master_to_slave_p99_ms": to_slave.get("p99"),
        "latency_master_to_slave_max_ms": to_slave.get("max"),
        "latency_slave_to_estimate_p50_ms": to_estimate.get("p50"),
        "latency_slave_to_estimate_p99_ms": to_estimate.get("p99"),
        "latency_slave_to_estimate_max_ms": to_estimate.get("max"),
        "latency_end_to_end_p99_ms": (
            None if None in p99s else round(sum(float(p) for p in p99s if p is not None), 4)
        ),
        "messages_lost": int(lost.get("total", 0)),
        "messages_lost_detail": {k: v for k, v in lost.items() if k != "total"},
        "messaging_joint_states_at_service_hz": (summary.get("rates_hz") or {}).get(
            "joint_states_at_service"
        ),
        "messaging_service_processing_p50_ms": processing.get("p50"),
        "messaging_service_processing_p99_ms": processing.get("p99"),
        "messaging_cpu_percent_of_one_core": summary.get("cpu_percent_of_one_core"),
        "messaging_loop_overruns": summary.get("loop_overruns"),
        "service_peak_rss_mb_demo": summary.get("service_peak_rss_mb"),
    }


def realtime_figures(summary: dict[str, Any], floor: dict[str, Any] | None) -> dict[str, Any]:
    """Return the 1 kHz budget of a demo run: CPU per process against the Zenoh floor.

    ``floor`` is the summary of a second run of the same demo with the service as its Zenoh
    floor (``--zenoh-floor``: the same subscriptions and publication, no work).
    """
    cpu = summary.get("cpu_percent") or {}
    floor_cpu = (floor or {}).get("cpu_percent") or {}
    service, service_floor = cpu.get("service"), floor_cpu.get("service")
    fractions = summary.get("loop_overrun_fraction") or {}
    loops = summary.get("loops") or {}
    ticks = {name: (loop or {}).get("ticks_fraction") for name, loop in loops.items()}
    known_fractions = [v for v in fractions.values() if v is not None]
    known_ticks = [v for v in ticks.values() if v is not None]
    return {
        "service_cpu_percent_at_1khz": service,
        "service_zenoh_floor_cpu_percent": service_floor,
        "service_cpu_above_floor_points": (
            None if service is None or service_floor is None else round(service - service_floor, 1)
        ),
        "demo_cpu_percent_total": cpu.get("total"),
        "demo_cpu_percent_by_process": {k: v for k, v in cpu.items() if k != "total"},
        "demo_slave_holds": summary.get("slave_holds"),
        "demo_loop_overrun_fraction": max(known_fractions) if known_fractions else None,
        "demo_loop_overrun_fraction_by_process": fractions,
        "demo_loop_ticks_fraction": min(known_ticks) if known_ticks else None,
        "demo_load_average_at_start": summary.get("machine_load_average_at_start"),
    }
