"""Figure 2 of ``teleop-force bench``: identification speed as a multiple of real time.

Over the same recordings (two, ``samples`` in all at 1 kHz), three things are timed:

* the whole pipeline, :func:`~teleop_force.identification.pipeline.identify_model` with the batch
  wavelet-network fit (what ``teleop-force identify --wn-fit batch`` does after reading the
  files): the filtered regressor
  (:func:`~teleop_force.identification.filtered_regressor.filter_signals`),
  the rigid-body least squares, the network's batch fit and the training figures;
* its filtered-regressor stage alone (:func:`~teleop_force.identification.pipeline.prepare`);
* the friction-fit stage alone on those precomputed filtered signals,
  :func:`~teleop_force.identification.wavelet_training.train_wavelet_network`: once with the batch
  ridge fit
  (:func:`~teleop_force.friction.batch_fit.fit_batch`) and once with one pass of the
  Lyapunov adaptation (:meth:`~teleop_force.friction.adaptation.LyapunovAdapter.run`).

Each figure is ``recorded seconds / wall seconds``; CPU seconds are reported alongside.

All figures are the **steady state**: the batch fit's compiled kernel
(:mod:`teleop_force.friction.kernels`, numba) is loaded before anything is timed
(:func:`~teleop_force.friction.kernels.warm_up`). What that costs once per process is
reported separately: ``identify_jit_first_call_s`` (this process: the compiled code read from
numba's disk cache, or compiled when there is none) and ``identify_jit_compile_s`` (a fresh
compilation, measured in a subprocess with an empty cache directory).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from teleop_force.bench.measure import Stopwatch, stopwatch
from teleop_force.friction import kernels
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.kinds import FrictionKind
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.pipeline import (
    WaveletOptions,
    identify_model,
    prepare,
    typical_inertia,
)
from teleop_force.identification.wavelet_training import train_wavelet_network
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.omni import omni_description


@dataclass
class IdentificationTiming:
    """What the identification benchmark measured.

    Attributes:
        samples: Samples in all recordings.
        recorded_s: Their duration at 1 kHz.
        pipeline, prepare, batch, adaptive: Wall and CPU time of each part (module docstring).
        batch_sizes, adaptive_sizes: Active wavelets per joint after each friction fit.
        model: The identified model (benchmark model of the other figures).
        jit_first_call_s: The kernel's first call in this process (disk cache or compile).
        jit_compile_s: A fresh compilation of the kernel (None if it could not be measured).

    """

    samples: int
    recorded_s: float
    pipeline: Stopwatch
    prepare: Stopwatch
    batch: Stopwatch
    adaptive: Stopwatch
    batch_sizes: list[int] = field(default_factory=list)
    adaptive_sizes: list[int] = field(default_factory=list)
    model: DynamicModel | None = None
    jit_first_call_s: float | None = None
    jit_compile_s: float | None = None

    def x_realtime(self, part: Stopwatch) -> float:
        """Return ``recorded_s`` over the part's wall time."""
        return self.recorded_s / part.wall_s if part.wall_s > 0 else float("inf")

    def figures(self) -> dict[str, Any]:
        """Return the JSON figures (keys carry their units)."""
        out: dict[str, Any] = {
            "identify_samples": self.samples,
            "identify_recorded_s": round(self.recorded_s, 3),
        }
        for name, part in (
            ("batch", self.batch),
            ("adaptive", self.adaptive),
            ("pipeline", self.pipeline),
            ("filter_signals", self.prepare),
        ):
            out[f"identify_{name}_x_realtime"] = round(self.x_realtime(part), 2)
            out[f"identify_{name}_wall_s"] = round(part.wall_s, 3)
            out[f"identify_{name}_cpu_s"] = round(part.cpu_s, 3)
        out["identify_batch_wavelets_per_joint"] = self.batch_sizes
        for key, value in (("first_call", self.jit_first_call_s), ("compile", self.jit_compile_s)):
            out[f"identify_jit_{key}_s"] = None if value is None else round(value, 3)
        out["identify_adaptive_wavelets_per_joint"] = self.adaptive_sizes
        return out


def time_identification(
    recordings: Sequence[Recording], log: Callable[[str], None] = lambda s: None
) -> IdentificationTiming:
    """Run and time the pipeline, its filtered-regressor stage and both friction fits."""
    first_call_s = kernels.warm_up()
    log(f"identify: compiled kernel loaded in {first_call_s:.2f} s (not in the figures)")
    compile_s = fresh_compile_seconds()
    description = omni_description()
    samples = sum(r.t_s.size for r in recordings)
    recorded_s = samples * float(recordings[0].t_s[1] - recordings[0].t_s[0])
    log(f"identify: whole pipeline (batch WN) on {samples} samples")
    with stopwatch() as pipeline:
        model, _ = identify_model(
            recordings, description, FrictionKind.WN, wavelet=WaveletOptions("batch")
        )
    log(f"  {pipeline.wall_s:.1f} s wall; the filtered-regressor stage alone")
    with stopwatch() as prepare_time:
        prepared, base = prepare(recordings, description, model.filter_config)
    network = model.friction
    if not isinstance(network, WaveletNetwork) or network.fallback is None:
        raise RuntimeError("identify did not produce a wavelet network with its fallback")
    inertia = typical_inertia(prepared, description, base, model.base_values)
    log(f"  {prepare_time.wall_s:.1f} s wall")
    results: dict[str, tuple[Stopwatch, list[int]]] = {}
    for method in ("batch", "adaptive"):
        log(f"identify: the friction fit alone, {method}")
        fallback = CoupledCoulombViscous.from_dict(network.fallback.to_dict())
        with stopwatch() as watch:
            trained, _ = train_wavelet_network(
                prepared,
                description,
                model.base_values,
                model.offsets_nm,
                fallback,
                WaveletOptions(method, passes=1),
                inertia_kgm2=inertia,
            )
        results[method] = (watch, list(trained.parameter_counts()))
        log(f"  {watch.wall_s:.1f} s wall")
    return IdentificationTiming(
        samples=samples,
        recorded_s=recorded_s,
        pipeline=pipeline,
        prepare=prepare_time,
        batch=results["batch"][0],
        adaptive=results["adaptive"][0],
        batch_sizes=results["batch"][1],
        adaptive_sizes=results["adaptive"][1],
        model=model,
        jit_first_call_s=first_call_s,
        jit_compile_s=compile_s,
    )


def fresh_compile_seconds(timeout_s: float = 300.0) -> float | None:
    """Seconds to compile the batch fit's kernel from scratch (subprocess, empty cache)."""
    code = "from teleop_force.friction import kernels; print(kernels.warm_up())"
    with tempfile.TemporaryDirectory(prefix="teleop-bench-numba-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        try:
            proc = subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True,
                timeout=timeout_s, check=True,
            )  # fmt: skip
            return float(proc.stdout.strip().splitlines()[-1])
        except (subprocess.SubprocessError, OSError, ValueError, IndexError):
            return None
