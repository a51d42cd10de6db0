"""Figure 6 of ``teleop-force bench``: whole recordings through the batch path, from the CLI.

A 10-minute 1 kHz session (a simulated palpation, tiled in time) is written as an interchange
CSV and as an MCAP session; then, each as a subprocess and timed from process start to exit
(the numba cache warmed by a first run on a short file):

* ``teleop-force estimate M SESSION.csv -o F.csv``: ``estimate_cli_x_realtime``;
* ``teleop-force replay SESSION.mcap --with-service --record OUT.mcap --model M``, today's
  model over a recorded session: ``reestimate_cli_x_realtime``.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: Length of the session the figures are measured on [s].
SESSION_S = 600.0
#: Length of the simulated palpation that is tiled into it [s].
TILE_S = 60.0


def tiled_palpation(duration_s: float, tile_s: float, seed: int = 0) -> dict[str, np.ndarray]:
    """Simulate a palpation of ``tile_s`` and repeat it up to ``duration_s``, time running on."""
    from teleop_force.bench.data import palpation_arrays

    tile = palpation_arrays(min(tile_s, duration_s), seed)
    n_tile = tile["t_s"].size
    n = round(duration_s * 1000)
    reps = -(-n // n_tile)
    out = {k: np.concatenate([v] * reps)[:n] for k, v in tile.items() if k != "t_s"}
    out["t_s"] = np.arange(n) * 1e-3
    return out


def _timed(argv: Sequence[str]) -> float:
    """Run ``argv``; return its wall time from process start to exit [s] (raise on failure)."""
    started = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        tail = " | ".join(done.stderr.strip().splitlines()[-3:])
        raise RuntimeError(f"{' '.join(argv[2:5])} failed ({done.returncode}): {tail}")
    return wall


def batch_figures(
    model_path: Path,
    work_dir: Path,
    log: Callable[[str], None] = lambda s: None,
    duration_s: float = SESSION_S,
) -> dict[str, Any]:
    """Write the session files, time the two commands; return the figures (keys with units)."""
    from teleop_force.bench.data import write_replay_session
    from teleop_force.io.interchange_csv import Recording, write_interchange_csv

    arrays = tiled_palpation(duration_s, TILE_S)
    csv_path = work_dir / "batch_session.csv"
    mcap_path = work_dir / "batch_session.mcap"
    short_csv = work_dir / "batch_warmup.csv"
    short_mcap = work_dir / "batch_warmup.mcap"
    log(f"batch: writing a {duration_s:g} s session (CSV and MCAP)")
    for path, rows in ((csv_path, arrays["t_s"].size), (short_csv, 2000)):
        write_interchange_csv(path, Recording(
            arrays["t_s"][:rows], arrays["q_rad"][:rows], arrays["tau_nm"][:rows],
            arrays["force_n"][:rows],
        ))  # fmt: skip
    write_replay_session(mcap_path, **arrays, model_path=str(model_path))
    write_replay_session(short_mcap, **{k: v[:2000] for k, v in arrays.items()},
                         model_path=str(model_path))  # fmt: skip
    cli = [sys.executable, "-m", "teleop_force.cli.main"]

    def estimate(source: Path) -> float:
        return _timed([*cli, "estimate", str(model_path), str(source),
                       "-o", str(work_dir / "batch_forces.csv")])  # fmt: skip

    def reestimate(source: Path) -> float:
        target = work_dir / "batch_reestimated.mcap"
        target.unlink(missing_ok=True)
        return _timed([*cli, "replay", str(source), "--with-service", "--record", str(target),
                       "--model", str(model_path)])  # fmt: skip

    estimate(short_csv)  # numba's cache warm, as in everyday use
    estimate_wall = estimate(csv_path)
    log(f"  estimate: {duration_s:g} s in {estimate_wall:.2f} s")
    reestimate(short_mcap)
    reestimate_wall = reestimate(mcap_path)
    log(f"  re-estimate: {duration_s:g} s in {reestimate_wall:.2f} s")
    return {
        "batch_session_s": duration_s,
        "estimate_cli_wall_s": round(estimate_wall, 3),
        "estimate_cli_x_realtime": round(duration_s / estimate_wall, 1),
        "reestimate_cli_wall_s": round(reestimate_wall, 3),
        "reestimate_cli_x_realtime": round(duration_s / reestimate_wall, 1),
    }
