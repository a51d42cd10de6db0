"""``teleop-force bench``: performance figures of this machine, measured in one run.

Seven figures, each measured in the same run as its reference so that it holds as a ratio on
a noisy machine (see BENCHMARKS.md for a full run and what was optimised):

1. the 1 kHz estimation step (:mod:`teleop_force.bench.estimation`) in µs and as a multiple
   of one ``pin.rnea`` call on the same model;
2. identification over 240,000 samples (:mod:`teleop_force.bench.identification`) as a
   multiple of real time: the friction-fit stage alone (batch, adaptive) and the whole
   pipeline;
3. messaging latency and loss of the headless demo, and its 1 kHz budget: CPU per process, the
   service against its Zenoh floor (a second run with ``--zenoh-floor``), slave holds, loop
   overruns and ticks (:mod:`teleop_force.bench.messaging`);
4. replay throughput through the service (:mod:`teleop_force.bench.replay`);
5. the service's peak memory, and how the figures grow with the number of wavelets per
   joint network and with the recording's length;
6. ``estimate`` and the re-estimation of a recording on a 10-minute session, from the CLI,
   process start included (:mod:`teleop_force.bench.batch`);
7. the cold start: from the ``demo`` command to its first estimate on an empty numba cache,
   the compile time of each kernel group, and the same on the warm cache
   (:mod:`teleop_force.bench.cold_start`), with the shipped model.
8. CDR encode and decode per ROS 2 message type, against the wire format's
   (:mod:`teleop_force.bench.cdr`).

Inputs are generated (:mod:`teleop_force.bench.data`). :func:`run_bench` returns one dict
whose keys name the figure and its unit; ``teleop-force bench --json`` prints it as one JSON
object on stdout, progress goes to stderr.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from teleop_force.bench.measure import rounded, stopwatch

if TYPE_CHECKING:
    from teleop_force.bench.estimation import StepTiming
    from teleop_force.identification.dynamic_model import DynamicModel

#: Wavelets per joint network of the scaling figures.
WAVELET_SETTINGS = (100, 300, 1000)
#: Recording lengths of the replay scaling figures [s] (full run, quick run).
REPLAY_LENGTHS_S = (10.0, 30.0, 60.0)
QUICK_REPLAY_LENGTHS_S = (1.0, 2.0)

#: The issue's goals: figure -> (comparison, bound).
GOALS: dict[str, tuple[str, float]] = {
    "estimate_step_p99_us": ("<=", 20.0),
    "estimate_step_vs_rnea": ("<=", 10.0),
    "identify_batch_x_realtime": (">=", 200.0),
    "identify_adaptive_x_realtime": (">=", 20.0),
    "latency_master_to_slave_p99_ms": ("<=", 2.0),
    "latency_slave_to_estimate_p99_ms": ("<=", 2.0),
    "messages_lost": ("<=", 0.0),
    "demo_slave_holds": ("<=", 0.0),
    "demo_loop_overrun_fraction": ("<=", 0.01),
    "demo_loop_ticks_fraction": (">=", 0.999),
    "service_cpu_above_floor_points": ("<=", 15.0),
    "demo_cpu_percent_total": ("<=", 140.0),
    "replay_x_realtime": (">=", 50.0),
    "estimate_cli_x_realtime": (">=", 100.0),
    "reestimate_cli_x_realtime": (">=", 50.0),
}


@dataclass(frozen=True)
class BenchOptions:
    """What :func:`run_bench` measures and how long.

    Attributes:
        quick: Short run (smoke test): small sizes everywhere.
        estimation: Time the estimation step (figure 1).
        identify_samples: Samples of the identification figures (240,000 = 4 min at 1 kHz).
        identify_simulated_s: Seconds simulated per recording at most: a longer recording is
            made of two 22 s periods of the multisine, the second one repeated.
        estimate_samples: Timed estimation steps of the main figure (half per scaling model).
        messaging: Run the demo for the messaging figures.
        messaging_duration_s: How long the demo runs once everything is up.
        messaging_model: ``bench`` (the benchmark's wavelet-network model) or ``shipped``.
        replay: Run the replay figures.
        replay_lengths_s: Lengths of the replayed sessions.
        replay_wavelets_length_s: Length of the session replayed for the wavelet scaling.
        wavelet_settings: Wavelets per joint network of the scaling figures.
        isolated_replays: One worker process per replay (clean memory figures).
        batch: Time ``estimate`` and the re-estimation of a recording from the CLI.
        batch_session_s: Length of the session of the batch figures.
        cold_start: Run the cold-start figures (two demos, the first on an empty numba cache).
        cold_start_duration_s: How long each of those demos runs from its first estimate.
        cdr: Time CDR encode and decode per ROS 2 message type.
        cdr_samples: Timed calls per message type and direction.
        work_dir: Where models and sessions are written (default: a temporary folder).
        seed: Seed of every simulation.

    """

    quick: bool = False
    estimation: bool = True
    identify_samples: int = 240_000
    identify_simulated_s: float = 44.0
    estimate_samples: int = 20_000
    messaging: bool = True
    messaging_duration_s: float = 60.0
    messaging_model: str = "bench"
    replay: bool = True
    replay_lengths_s: tuple[float, ...] = REPLAY_LENGTHS_S
    replay_wavelets_length_s: float = 10.0
    wavelet_settings: tuple[int, ...] = WAVELET_SETTINGS
    isolated_replays: bool = True
    batch: bool = True
    batch_session_s: float = 600.0
    cold_start: bool = True
    cold_start_duration_s: float = 5.0
    cdr: bool = True
    cdr_samples: int = 20_000
    work_dir: Path | None = None
    seed: int = 0

    @classmethod
    def quick_run(cls, **changes: Any) -> BenchOptions:
        """Options of ``--quick``: every part, at small sizes (well under a minute)."""
        values: dict[str, Any] = {
            "quick": True,
            "identify_samples": 12_000,
            "identify_simulated_s": 6.0,
            "estimate_samples": 2_000,
            "messaging_duration_s": 5.0,
            "replay_lengths_s": QUICK_REPLAY_LENGTHS_S,
            "replay_wavelets_length_s": 0.5,
            "isolated_replays": False,
            "batch_session_s": 5.0,
            "cold_start_duration_s": 2.0,
            "cdr_samples": 1_000,
        }
        values.update(changes)
        return cls(**values)


def _distribution_version(name: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "?"


def _versions() -> dict[str, str]:
    import pinocchio

    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "pinocchio": str(pinocchio.__version__),
        "zenoh": _distribution_version("eclipse-zenoh"),
    }


def _parts(options: BenchOptions) -> list[str]:
    flags = {"estimation": options.estimation, "replay": options.replay,
             "messaging": options.messaging, "batch": options.batch,
             "cold-start": options.cold_start, "cdr": options.cdr}  # fmt: skip
    return ["identification"] + [name for name, on in flags.items() if on]


def _goals(result: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for key, (op, bound) in GOALS.items():
        value = result.get(key)
        met = None if value is None else (value <= bound if op == "<=" else value >= bound)
        out[key] = {"goal": f"{op} {bound:g}", "value": value, "met": met}
    return out


@dataclass(frozen=True)
class _BenchModel:
    """The identification's model (the benchmark model of the other figures), as saved.

    Attributes:
        model: The identified model with the found effects added.
        path: Where it is saved (the replay and the demo read it there).
        figures: The identification figures and the model's wavelet and effect counts.

    """

    model: DynamicModel
    path: Path
    figures: dict[str, Any]


@dataclass(frozen=True)
class _WaveletVariant:
    """The benchmark model with another number of wavelets per joint network.

    Attributes:
        setting: Wavelets per joint asked for, as the figures' key (``"300"``).
        path: Where the variant is saved.
        counts: Wavelets per joint network it actually has.
        timing: Its estimation step (``None`` when the estimation figures are off).

    """

    setting: str
    path: Path
    counts: list[int]
    timing: StepTiming | None


def run_bench(options: BenchOptions, log: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Measure every figure (see the module docstring); return them as one JSON-ready dict."""
    result = _run_header(options)
    with _work_folder(options.work_dir) as work_dir:
        with stopwatch() as total:
            # 2. identification first: its model is the benchmark model of the other figures
            bench_model = _identify(options, work_dir, log)
            result.update(bench_model.figures)
            # 1. the estimation step, and its growth with the wavelets
            palpation = _palpation(options, log)
            timings = _time_main_step(options, bench_model.model, palpation, log)
            variants = _wavelet_variants(options, bench_model.model, palpation, work_dir, log)
            result.update(_estimation_figures(timings, variants))
            result["wavelets_per_joint_by_setting"] = {
                v.setting: v.counts for v in variants
            } or None
            # 4-5. replay through the service, its memory, growth with length and wavelets
            result.update(_guarded_part(
                "replay", options.replay, _REPLAY_KEYS,
                lambda: _replay_figures(
                    options, palpation, bench_model.path, variants, work_dir, log
                ),
                log,
            ))  # fmt: skip
            # 3. messaging (the demo), the service's memory in it
            result.update(_guarded_part(
                "messaging", options.messaging, _MESSAGING_KEYS,
                lambda: _messaging_figures(options, bench_model.path, log), log,
            ))  # fmt: skip
            result.update(_service_memory(result))
            # 6. whole recordings through the batch path, from the CLI
            result.update(_guarded_part(
                "batch", options.batch, _BATCH_KEYS,
                lambda: _batch_figures(options, bench_model.path, work_dir, log), log,
            ))  # fmt: skip
            # 7. the cold start, from the command to the first estimate
            result.update(_guarded_part(
                "cold_start", options.cold_start, _COLD_START_KEYS,
                lambda: _cold_start_figures(options, log), log,
            ))  # fmt: skip
            # 8. CDR encode / decode per ROS 2 message type
            result.update(_guarded_part(
                "cdr", options.cdr, _CDR_KEYS, lambda: _cdr_figures(options, log), log
            ))  # fmt: skip
        result["bench_wall_s"] = round(total.wall_s, 2)
        result["bench_cpu_s"] = round(total.cpu_s, 2)
        result["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
        result["goals"] = _goals(result)
        if options.work_dir is not None:
            result["work_dir"] = str(work_dir)
        return result


def _run_header(options: BenchOptions) -> dict[str, Any]:
    """Describe the run: when, where, with what, which parts."""
    return {
        "bench": "teleop-force",
        "quick": options.quick,
        "date_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "cpu_count": os.cpu_count(),
        "load_average_start": [round(x, 2) for x in os.getloadavg()],
        "versions": _versions(),
        "parts": _parts(options),
    }


@contextmanager
def _work_folder(work: Path | None) -> Iterator[Path]:
    """Yield ``work`` (created), or a temporary folder removed afterwards when it is ``None``."""
    folder = Path(tempfile.mkdtemp(prefix="teleop-bench-")) if work is None else Path(work)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        yield folder
    finally:
        if work is None:
            shutil.rmtree(folder, ignore_errors=True)


def _identify(options: BenchOptions, work_dir: Path, log: Callable[[str], None]) -> _BenchModel:
    """Time the identification on simulated recordings; save its model with found effects."""
    from teleop_force.bench.data import (
        MULTISINE_PERIOD_S,
        SAMPLE_INTERVAL_S,
        identification_recordings,
        wavelet_counts,
        with_found_effects,
    )
    from teleop_force.bench.identification import time_identification

    per_recording = options.identify_samples // 2
    needed_s = per_recording * SAMPLE_INTERVAL_S
    simulated_s = (
        needed_s
        if needed_s <= options.identify_simulated_s
        else max(options.identify_simulated_s, 2 * MULTISINE_PERIOD_S)
    )
    log(f"simulating 2 x {simulated_s:g} s -> 2 x {per_recording} samples")
    recordings = identification_recordings(simulated_s, per_recording, options.seed)
    ident = time_identification(recordings, log)
    figures = ident.figures()
    assert ident.model is not None
    model = with_found_effects(ident.model)
    path = work_dir / "bench_model.json"
    model.save(path)
    figures["model_wavelets_per_joint"] = wavelet_counts(model)
    figures["model_found_effects"] = len(model.effects)
    return _BenchModel(model, path, figures)


def _palpation(options: BenchOptions, log: Callable[[str], None]) -> dict[str, np.ndarray]:
    """Simulate the palpation the estimation and replay figures use (empty if neither runs)."""
    from teleop_force.bench.data import palpation_arrays

    if not (options.estimation or options.replay):
        return {}
    longest = max(options.replay_lengths_s) if options.replay else 0.0
    duration = max(longest, options.replay_wavelets_length_s, 1.0)
    duration = max(duration, (options.estimate_samples + 600) / 1000.0)
    log(f"simulating a {duration:g} s palpation")
    return palpation_arrays(duration, options.seed)


def _time_main_step(
    options: BenchOptions,
    model: DynamicModel,
    palpation: dict[str, np.ndarray],
    log: Callable[[str], None],
) -> tuple[StepTiming, StepTiming] | None:
    """Time the benchmark model's ``step`` and ``update`` (``None`` when it is off)."""
    from teleop_force.bench.estimation import time_estimation_step

    if not options.estimation:
        return None
    log(f"estimation step: {options.estimate_samples} timed steps, as many updates")
    arrays = palpation["t_s"], palpation["q_rad"], palpation["tau_nm"]
    step = time_estimation_step(model, *arrays, options.estimate_samples)
    update = time_estimation_step(model, *arrays, options.estimate_samples, call="update")
    return step, update


def _wavelet_variants(
    options: BenchOptions,
    model: DynamicModel,
    palpation: dict[str, np.ndarray],
    work_dir: Path,
    log: Callable[[str], None],
) -> tuple[_WaveletVariant, ...]:
    """Save the model at each wavelet setting; time its estimation step if that part runs."""
    from teleop_force.bench.data import wavelet_counts, with_wavelets
    from teleop_force.bench.estimation import time_estimation_step

    if not (options.estimation or options.replay):
        return ()
    variants = []
    for per_joint in options.wavelet_settings:
        variant = with_wavelets(model, per_joint, options.seed)
        path = work_dir / f"bench_model_{per_joint}.json"
        variant.save(path)
        counts = wavelet_counts(variant)
        timing = None
        if options.estimation:
            timing = time_estimation_step(
                variant, palpation["t_s"], palpation["q_rad"], palpation["tau_nm"],
                max(500, options.estimate_samples // 2),
            )  # fmt: skip
            log(f"  {counts} wavelets: p50 {timing.p50_us:.1f} us")
        variants.append(_WaveletVariant(str(per_joint), path, counts, timing))
    return tuple(variants)


def _estimation_figures(
    timings: tuple[StepTiming, StepTiming] | None, variants: Sequence[_WaveletVariant]
) -> dict[str, Any]:
    """Return the estimation figures (all ``None`` when the step was not timed).

    ``estimate_step_*``: :meth:`ForceEstimator.step`, the service's call per joint state;
    ``estimate_update_*``: :meth:`ForceEstimator.update`, the step plus a ``ForceEstimate``.
    """
    figures: dict[str, Any] = dict.fromkeys(_ESTIMATION_KEYS)
    if timings is None:
        return figures
    step, update = timings
    figures.update(
        estimate_update_p50_us=rounded(update.p50_us),
        estimate_update_p99_us=rounded(update.p99_us),
        estimate_update_vs_rnea=rounded(update.vs_rnea, 2),
    )
    figures.update(
        estimate_step_p50_us=rounded(step.p50_us),
        estimate_step_p99_us=rounded(step.p99_us),
        estimate_step_max_us=rounded(step.max_us),
        estimate_step_mean_us=rounded(step.mean_us),
        estimate_step_cpu_p50_us=rounded(step.cpu_p50_us),
        estimate_step_cpu_p99_us=rounded(step.cpu_p99_us),
        rnea_us=rounded(step.rnea_us, 4),
        estimate_step_vs_rnea=rounded(step.vs_rnea, 2),
        estimate_step_p99_vs_rnea=rounded(step.p99_vs_rnea, 2),
        estimate_samples=step.samples,
        estimate_timer_overhead_us=rounded(step.timer_overhead_us, 4),
    )
    timed = [(v.setting, v.timing) for v in variants if v.timing is not None]
    figures.update(
        estimate_step_p50_us_by_wavelets={k: rounded(t.p50_us) for k, t in timed},
        estimate_step_p99_us_by_wavelets={k: rounded(t.p99_us) for k, t in timed},
        estimate_step_cpu_p99_us_by_wavelets={k: rounded(t.cpu_p99_us) for k, t in timed},
        estimate_step_vs_rnea_by_wavelets={k: rounded(t.vs_rnea, 2) for k, t in timed},
    )
    return figures


def _guarded_part(
    name: str,
    on: bool,
    keys: Sequence[str],
    measure: Callable[[], dict[str, Any]],
    log: Callable[[str], None],
) -> dict[str, Any]:
    """Measure one part's figures (``None`` when off; ``<name>_error`` on failure)."""
    figures: dict[str, Any] = dict.fromkeys(keys)
    if on:
        try:
            figures.update(measure())
        except (RuntimeError, OSError, ValueError, subprocess.SubprocessError) as exc:
            log(f"{name} figures failed: {exc}")
            figures[f"{name}_error"] = str(exc)
    return figures


def _service_memory(result: dict[str, Any]) -> dict[str, Any]:
    """Pick the service's peak memory: the demo's service process, else the replay worker."""
    demo_rss = result.get("service_peak_rss_mb_demo")
    replay_rss = result.get("replay_peak_rss_mb")
    return {
        "service_peak_rss_mb": demo_rss if demo_rss is not None else replay_rss,
        "service_peak_rss_source": (
            "demo service process" if demo_rss is not None
            else ("replay worker (service in-process)" if replay_rss is not None else None)
        ),
    }  # fmt: skip


def _replay_figures(
    options: BenchOptions,
    palpation: dict[str, np.ndarray],
    model_path: Path,
    variants: Sequence[_WaveletVariant],
    work_dir: Path,
    log: Callable[[str], None],
) -> dict[str, Any]:
    from teleop_force.bench.data import write_replay_session
    from teleop_force.bench.replay import run_workers

    def session(length_s: float) -> Path:
        path = work_dir / f"replay_{length_s:g}s.mcap"
        if not path.exists():
            n = round(length_s * 1000)
            arrays = {k: v[:n] for k, v in palpation.items()}
            write_replay_session(path, **arrays, model_path=str(model_path))
        return path

    jobs = [(session(length), model_path) for length in options.replay_lengths_s]
    wavelet_session = session(options.replay_wavelets_length_s)
    jobs += [(wavelet_session, variant.path) for variant in variants]
    log(f"replay: {len(jobs)} sessions through the service, as fast as possible")
    runs = run_workers(jobs, isolated=options.isolated_replays)
    by_length = runs[: len(options.replay_lengths_s)]
    by_wavelets = runs[len(options.replay_lengths_s) :]
    longest = by_length[-1]
    for run in runs:
        log(f"  {Path(run['session']).name} / {Path(run['model']).name}: x{run['x_realtime']}, "
            f"{run['peak_rss_mb']} MB")  # fmt: skip
    lengths = [f"{length:g}" for length in options.replay_lengths_s]
    settings = [variant.setting for variant in variants]
    return {
        "replay_x_realtime": longest["x_realtime"],
        "replay_recorded_s": longest["recorded_span_s"],
        "replay_wall_s": longest["wall_s"],
        "replay_publish_wall_s": longest["publish_wall_s"],
        "replay_messages_per_recorded_s": round(
            longest["messages_published"] / max(longest["recorded_span_s"], 1e-9), 1
        ),
        "replay_joint_states_lost": sum(r["joint_states_lost"] for r in runs),
        "replay_estimates_missing": sum(
            r["joint_states_expected"] - r["estimates_published"] for r in runs
        ),
        "replay_service_processing_p50_ms": (longest.get("processing_ms") or {}).get("p50"),
        "replay_service_processing_p99_ms": (longest.get("processing_ms") or {}).get("p99"),
        "replay_peak_rss_mb": longest["peak_rss_mb"],
        "replay_rss_before_replay_mb": longest["rss_before_replay_mb"],
        "replay_x_realtime_by_length_s": {
            k: r["x_realtime"] for k, r in zip(lengths, by_length, strict=True)
        },
        "replay_peak_rss_mb_by_length_s": {
            k: r["peak_rss_mb"] for k, r in zip(lengths, by_length, strict=True)
        },
        "replay_x_realtime_by_wavelets": {
            k: r["x_realtime"] for k, r in zip(settings, by_wavelets, strict=True)
        },
        "replay_peak_rss_mb_by_wavelets": {
            k: r["peak_rss_mb"] for k, r in zip(settings, by_wavelets, strict=True)
        },
        "replay_wavelets_session_s": options.replay_wavelets_length_s,
        "replay_isolated_workers": options.isolated_replays,
    }


def _batch_figures(
    options: BenchOptions, model_path: Path, work_dir: Path, log: Callable[[str], None]
) -> dict[str, Any]:
    from teleop_force.bench.batch import batch_figures

    return batch_figures(model_path, work_dir, log, duration_s=options.batch_session_s)


def _cold_start_figures(options: BenchOptions, log: Callable[[str], None]) -> dict[str, Any]:
    from teleop_force.bench.cold_start import measure_cold_start

    return measure_cold_start(options.cold_start_duration_s, None, log)


def _cdr_figures(options: BenchOptions, log: Callable[[str], None]) -> dict[str, Any]:
    from teleop_force.bench.cdr import cdr_figures

    log(f"cdr: encode and decode per ROS 2 message type, {options.cdr_samples} calls each")
    return cdr_figures(options.cdr_samples)


def _messaging_figures(
    options: BenchOptions, model_path: Path, log: Callable[[str], None]
) -> dict[str, Any]:
    from teleop_force.bench.messaging import messaging_figures, realtime_figures, run_demo

    log(f"messaging: headless demo for {options.messaging_duration_s:g} s")
    model = model_path if options.messaging_model == "bench" else None
    summary = run_demo(options.messaging_duration_s, model)
    figures = messaging_figures(summary)
    figures["messaging_model"] = options.messaging_model
    log(f"  the same demo with the service as its Zenoh floor ({options.messaging_duration_s:g} s)")
    floor = run_demo(options.messaging_duration_s, model, extra_args=("--zenoh-floor",))
    figures.update(realtime_figures(summary, floor))
    log(f"  service {figures['service_cpu_percent_at_1khz']} % of a core, Zenoh floor "
        f"{figures['service_zenoh_floor_cpu_percent']} %; all demo processes "
        f"{figures['demo_cpu_percent_total']} %; holds {figures['demo_slave_holds']}")  # fmt: skip
    log(f"  end-to-end p99 <= {figures['latency_end_to_end_p99_ms']} ms, "
        f"lost {figures['messages_lost']}")  # fmt: skip
    return figures


_ESTIMATION_KEYS = (
    "estimate_step_p50_us", "estimate_step_p99_us", "estimate_step_max_us",
    "estimate_step_mean_us", "estimate_step_cpu_p50_us", "estimate_step_cpu_p99_us", "rnea_us",
    "estimate_step_vs_rnea", "estimate_step_p99_vs_rnea", "estimate_samples",
    "estimate_timer_overhead_us", "estimate_step_p50_us_by_wavelets",
    "estimate_step_p99_us_by_wavelets", "estimate_step_cpu_p99_us_by_wavelets",
    "estimate_step_vs_rnea_by_wavelets", "estimate_update_p50_us", "estimate_update_p99_us",
    "estimate_update_vs_rnea",
)  # fmt: skip
#: Parts of ``teleop-force bench`` that ``--only`` selects (identification always runs: its
#: model is the benchmark model of the others).
PARTS = ("identification", "estimation", "replay", "messaging", "batch", "cold-start", "cdr")

_CDR_KEYS = (
    "cdr_encode_p50_us_by_type", "cdr_encode_p99_us_by_type", "cdr_decode_p50_us_by_type",
    "cdr_decode_p99_us_by_type", "wire_encode_p50_us_by_type", "wire_decode_p50_us_by_type",
    "cdr_samples",
)  # fmt: skip

_REPLAY_KEYS = (
    "replay_x_realtime", "replay_peak_rss_mb", "replay_x_realtime_by_length_s",
    "replay_peak_rss_mb_by_length_s", "replay_x_realtime_by_wavelets",
    "replay_peak_rss_mb_by_wavelets",
)  # fmt: skip


_MESSAGING_KEYS = (
    "latency_master_to_slave_p50_ms", "latency_master_to_slave_p99_ms",
    "latency_master_to_slave_max_ms", "latency_slave_to_estimate_p50_ms",
    "latency_slave_to_estimate_p99_ms", "latency_slave_to_estimate_max_ms",
    "latency_end_to_end_p99_ms", "messages_lost", "service_peak_rss_mb_demo",
    "messaging_duration_s", "messaging_ok", "messaging_model",
    "service_cpu_percent_at_1khz", "service_zenoh_floor_cpu_percent",
    "service_cpu_above_floor_points", "demo_cpu_percent_total", "demo_slave_holds",
    "demo_loop_overrun_fraction", "demo_loop_ticks_fraction",
)  # fmt: skip

_COLD_START_KEYS = tuple(
    f"{run}_{name}"
    for run in ("cold_start", "warm_start")
    for name in (
        "first_estimate_s", "warm_up_s", "warm_up_cached", "compile_s_by_group", "up_after_s",
        "estimated_fraction",
    )
)  # fmt: skip

_BATCH_KEYS = (
    "estimate_cli_x_realtime", "reestimate_cli_x_realtime", "estimate_cli_wall_s",
    "reestimate_cli_wall_s", "batch_session_s",
)  # fmt: skip


def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``teleop-force bench`` to ``parser``."""
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    parser.add_argument(
        "--quick", action="store_true", help="short run at small sizes (smoke test)"
    )
    parser.add_argument(
        "--only",
        default=None,
        metavar="PART[,PART]",
        help="run only these parts: " + ", ".join(PARTS) + " (identification "
        "always runs: it makes the benchmark model); e.g. --only identification",
    )
    parser.add_argument("--no-messaging", action="store_true", help="skip the demo (latency, loss)")
    parser.add_argument("--no-replay", action="store_true", help="skip the replay figures")
    parser.add_argument(
        "--no-cold-start", action="store_true", help="skip the cold start (two demos, ~1 min)"
    )
    parser.add_argument(
        "--messaging-duration",
        type=float,
        default=None,
        metavar="S",
        help="seconds the demo runs (default 60; 5 with --quick)",
    )
    parser.add_argument(
        "--messaging-model",
        choices=("bench", "shipped"),
        default="bench",
        help="model of the demo's service: the benchmark's WN model or the shipped one",
    )
    parser.add_argument(
        "--identify-samples",
        type=int,
        default=None,
        metavar="N",
        help="samples of the identification figures (default 240000)",
    )
    parser.add_argument(
        "--estimate-samples",
        type=int,
        default=None,
        metavar="N",
        help="timed estimation steps (default 20000)",
    )
    parser.add_argument(
        "--work-dir",
        default=None,
        metavar="DIR",
        help="keep the generated models and sessions in DIR",
    )


def options_from_args(args: argparse.Namespace) -> BenchOptions:
    """:class:`BenchOptions` of parsed ``teleop-force bench`` arguments."""
    from teleop_force.errors import ConfigurationError

    parts = set(PARTS)
    if args.only is not None:
        parts = {p.strip() for p in args.only.split(",") if p.strip()}
        unknown = parts - set(PARTS)
        if unknown or not parts:
            raise ConfigurationError(
                f"--only: unknown part(s) {', '.join(sorted(unknown)) or '(none)'}; "
                f"choose from {', '.join(PARTS)}"
            )
    changes: dict[str, Any] = {
        "estimation": "estimation" in parts,
        "messaging": not args.no_messaging and "messaging" in parts,
        "replay": not args.no_replay and "replay" in parts,
        "batch": "batch" in parts,
        "cold_start": not args.no_cold_start and "cold-start" in parts,
        "cdr": "cdr" in parts,
        "messaging_model": args.messaging_model,
    }
    if args.messaging_duration is not None:
        if not args.messaging_duration > 0:
            raise ConfigurationError(
                f"--messaging-duration must be > 0, got {args.messaging_duration}"
            )
        changes["messaging_duration_s"] = args.messaging_duration
    if args.identify_samples is not None:
        if args.identify_samples < 4000:
            raise ConfigurationError("--identify-samples must be >= 4000")
        changes["identify_samples"] = args.identify_samples
    if args.estimate_samples is not None:
        if args.estimate_samples < 100:
            raise ConfigurationError("--estimate-samples must be >= 100")
        changes["estimate_samples"] = args.estimate_samples
    if args.work_dir is not None:
        changes["work_dir"] = Path(args.work_dir)
    return BenchOptions.quick_run(**changes) if args.quick else BenchOptions(**changes)


def format_table(result: dict[str, Any]) -> str:
    """Format the goals and main figures as a plain-text table (the non-JSON output)."""
    lines = [f"{'figure':<34} {'value':>14}  goal"]
    for key, goal in result.get("goals", {}).items():
        met = {True: "met", False: "NOT met", None: "n/a"}[goal["met"]]
        value = goal["value"]
        shown = "-" if value is None else f"{value:.4g}"
        lines.append(f"{key:<34} {shown:>14}  {goal['goal']} ({met})")
    for key in ("rnea_us", "estimate_step_p50_us", "identify_pipeline_x_realtime",
                "service_peak_rss_mb", "load_average_start", "load_average_end"):  # fmt: skip
        lines.append(f"{key:<34} {result.get(key)!s:>14}")
    return "\n".join(lines)


def _cell(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def markdown_tables(result: dict[str, Any]) -> str:
    """Format a run's goals, main figures and scaling figures as Markdown tables."""
    lines = ["| figure | value | goal | met |", "|---|---:|---|---|"]
    for key, goal in result.get("goals", {}).items():
        met = {True: "yes", False: "**no**", None: "-"}[goal["met"]]
        lines.append(f"| `{key}` | {_cell(goal['value'])} | {goal['goal']} | {met} |")
    lines += ["", "| figure | value |", "|---|---:|"]
    for key, value in result.items():
        if key == "goals" or isinstance(value, dict) or key in result.get("goals", {}):
            continue
        lines.append(f"| `{key}` | {_cell(value) if not isinstance(value, list) else value} |")
    tables = (
        ("wavelets per joint network", "wavelets_per_joint_by_setting", (
            "estimate_step_p50_us_by_wavelets", "estimate_step_p99_us_by_wavelets",
            "estimate_step_cpu_p99_us_by_wavelets", "estimate_step_vs_rnea_by_wavelets",
            "replay_x_realtime_by_wavelets", "replay_peak_rss_mb_by_wavelets",
        )),
        ("recording length [s]", None, (
            "replay_x_realtime_by_length_s", "replay_peak_rss_mb_by_length_s",
        )),
    )  # fmt: skip
    for title, counts_key, keys in tables:
        present = [k for k in keys if isinstance(result.get(k), dict)]
        if not present:
            continue
        settings = list(result[present[0]])
        lines += ["", f"| {title} | " + " | ".join(settings) + " |"]
        lines.append("|---|" + "---:|" * len(settings))
        if counts_key and isinstance(result.get(counts_key), dict):
            counts = result[counts_key]
            lines.append("| actual (joints 1, 2, 3) | " + " | ".join(
                ", ".join(str(c) for c in counts.get(s, [])) for s in settings
            ) + " |")  # fmt: skip
        for key in present:
            row = result[key]
            lines.append(f"| `{key}` | " + " | ".join(_cell(row.get(s)) for s in settings) + " |")
    return "\n".join(lines)
