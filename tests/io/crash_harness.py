"""Run a recording script in a subprocess, SIGKILL it once enough is durable (crash tests)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def kill_when_durable(
    script: str, path: Path, durable_wanted: int, timeout_s: float = 30.0
) -> tuple[int, int, str]:
    """Run ``script`` (argv[1] = ``path``), which prints its durable message count as it grows.

    Once it has printed ``durable_wanted`` or more (or after ``timeout_s``, or if it stops
    printing), SIGKILL it; return ``(last durable count, return code, its stderr)``.
    """
    proc = subprocess.Popen(
        [sys.executable, "-c", script, str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        cwd=REPO,
    )
    durable = 0
    deadline = time.monotonic() + timeout_s
    try:
        assert proc.stdout is not None
        while durable < durable_wanted and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            durable = int(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.close()
        stderr = proc.stderr.read()
        proc.stderr.close()
    return durable, proc.returncode, stderr
