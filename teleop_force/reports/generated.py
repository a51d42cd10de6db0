"""The report over generated plants: per seed the drawn structure and what the defaults do on it.

For each seed, :func:`~teleop_force.simulation.generator.draw_plant` draws a plant
(docs/plant_generator.md) and :func:`run_seed` measures, all held out:

- **identification**: ``identify``'s default for the Omni behind the guards
  (:func:`~teleop_force.identification.guards.identify_guarded`) on the identification
  motion; its relative RMS per joint on the test motion (another kind), and the coupled CV's
  (identified on the same motion) on the same data: WN vs CV. The guards' fallbacks and the
  joints the WN kept (chosen on an inner split of the identification motion);
- **contact force**: that model's batch estimate on the palpation session against the true
  force (:func:`~teleop_force.reports.accuracy.accuracy_figures`): RMS error in contact, as %
  of the RMS contact force;
- **residual loop**: :func:`~teleop_force.residual.acceptance.trace_residual_tested` on a
  clean session and on one with the drawn effect planted: before/after (the loop's blocks,
  and the test third), what it named (:class:`~teleop_force.reports.blind_tests.BlindCase`'s
  rules: joint, variable, kind), false effects, fallbacks.

``teleop-force generated-report --seeds 1-20 -o DIR`` writes ``seeds.jsonl`` (one line a
seed, appended as each finishes) and ``report.md`` (the tables).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from time import perf_counter
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.friction.kinds import FrictionKind
from teleop_force.identification.guards import identify_guarded
from teleop_force.identification.pipeline import evaluate_model, identify_model
from teleop_force.io.interchange_csv import Recording
from teleop_force.reports.accuracy import BatchEstimate, CascadeReference, accuracy_figures
from teleop_force.reports.blind_tests import EXPECTED, BlindCase
from teleop_force.residual.acceptance import trace_residual_tested
from teleop_force.robots.kinds import RobotKind
from teleop_force.robots.omni import omni_description
from teleop_force.robots.registry import robot_defaults
from teleop_force.simulation.generator import DrawnPlant, draw_plant
from teleop_force.simulation.generator_spec import SPEC
from teleop_force.simulation.session import SimulatedSession

#: Session seeds of a plant seed ``s``: ``_SESSION_BASE * s + k``.
_SESSION_BASE = 101


def parse_seeds(text: str) -> tuple[int, ...]:
    """Parse ``1-20`` or ``3,5,9`` (or both, comma-separated) into seeds."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            if "-" in part:
                low, high = (int(x) for x in part.split("-", 1))
                seeds += range(low, high + 1)
            elif part.strip():
                seeds.append(int(part))
    except ValueError:
        raise ConfigurationError(f"seeds must look like 1-20 or 3,5,9, got {text!r}") from None
    if not seeds or any(s < 0 for s in seeds):
        raise ConfigurationError(f"need seeds >= 0, got {text!r}")
    return tuple(seeds)


def _recording(session: SimulatedSession) -> Recording:
    return Recording(session.t_s, session.q_rad, session.tau_nm)


def _floats(values: Any) -> list[float]:
    return [float(x) for x in np.asarray(values, dtype=float).reshape(-1)]


def _is_cable_friction(plant: DrawnPlant, found: dict[str, Any]) -> bool:
    """Whether ``found`` is the drawn cable: joint 2 or 3 on the other's velocity alone.

    The drawn cable acts on ``qd2 - r qd3`` with ``r`` drawn; the coupled CV has ``r = 1``,
    so the difference is plant structure the model lacks, not a false effect.
    """
    other = {2: "qd3", 3: "qd2"}.get(int(found["joint"]))
    return bool(
        plant.cable_form != "none"
        and other is not None
        and set(found["depends_on"]) <= {other, f"qd{found['joint']}"}
    )


def _loop_case(plant: DrawnPlant, seed: int, planted: bool) -> dict[str, Any]:
    effects = (plant.effect(),) if planted else ()
    motion, duration = plant.identification_motion, SPEC.motion.residual_s
    session = plant.session(motion, duration, seed, effects=effects)
    report = trace_residual_tested([_recording(session)], omni_description())
    found = tuple({**e.to_json(), "variable": e.spec.variable} for e in report.effects)
    name = plant.planted_effect if planted else "clean"
    joint, variables, kinds = EXPECTED.get(name, (None, (), ()))
    case = BlindCase(
        name, joint, variables, found, tuple(report.before), tuple(report.after), (),
        None, kinds, "generated",
    )  # fmt: skip
    cable = [f for f in case.false_effects if _is_cable_friction(plant, f)]
    return {
        "effect": name,
        "named": case.named is not None,
        "false_effects": [f["description"] for f in case.false_effects if f not in cable],
        "friction_shapes": [f["description"] for f in (*case.friction_shapes, *cable)],
        "found": [f["description"] for f in found],
        "before": _floats(report.before),
        "after": _floats(report.after),
        "test_before": _floats(report.test_before),
        "test_after": _floats(report.test_after),
        "friction": report.friction,
        "fallbacks": list(report.fallbacks),
        "failed": report.failed,
        "tested": [dict(t) for t in report.tested],
    }


def run_seed(seed: int, log: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """Draw the plant of ``seed`` and measure it (module docstring); JSON-ready."""
    started = perf_counter()
    plant = draw_plant(seed)
    base = _SESSION_BASE * seed
    m = SPEC.motion
    identification = plant.session(plant.identification_motion, m.identification_s, base)
    test = plant.session(plant.test_motion, m.test_s, base + 1)
    palpation = plant.session("palpation", m.palpation_s, base + 2)
    defaults = robot_defaults(RobotKind.OMNI)
    kind = FrictionKind(defaults.friction)
    description = omni_description()
    model, _, guards = identify_guarded(
        [_recording(identification)],
        description,
        kind,
        offsets=defaults.offsets,
        sticking=defaults.sticking_with(kind),
        count_observer=defaults.count_observer,
    )
    default_rms = evaluate_model(model, [_recording(test)])["relative_rms"]
    cv_kind = FrictionKind.COUPLED_CV
    cv_model, _ = identify_model(
        [_recording(identification)],
        description,
        cv_kind,
        offsets=defaults.offsets,
        sticking=defaults.sticking_with(cv_kind),
        count_observer=defaults.count_observer,
    )
    cv_rms = evaluate_model(cv_model, [_recording(test)])["relative_rms"]
    force_hat = BatchEstimate()(model, palpation)
    reference = CascadeReference(model.filter_config)(
        palpation.f_tip_in_base_n, palpation.sample_interval_s
    )
    force = accuracy_figures(palpation, force_hat, reference, model.filter_config.warmup_s)
    clean = _loop_case(plant, base + 3, planted=False)
    effect = _loop_case(plant, base + 4, planted=True)
    result = {
        "seed": seed,
        "structure": plant.structure(),
        "default_friction": guards.chosen,
        "guards": guards.to_dict(),
        "default_test_rms": _floats(default_rms),
        "coupled_cv_test_rms": _floats(cv_rms),
        "contact_error_pct": float(force["contact_error_pct"]),
        "rms_contact_force_n": float(force["rms_contact_force_n"]),
        "clean": clean,
        "effect": effect,
        "wall_s": round(perf_counter() - started, 1),
    }
    log(
        f"seed {seed}: {guards.chosen}, test RMS {_pct(default_rms)} (CV {_pct(cv_rms)}),"
        f" contact error {force['contact_error_pct']:.2f} %, clean found {clean['found']},"
        f" {effect['effect']} named {effect['named']} (found {effect['found']})"
        f" in {result['wall_s']} s"
    )
    return result


def _pct(values: Any) -> str:
    return " / ".join(f"{100 * float(v):.1f}" for v in np.asarray(values).reshape(-1))


def run_report(
    seeds: Sequence[int], folder: Path, log: Callable[[str], None] = print
) -> list[dict[str, Any]]:
    """Run :func:`run_seed` on ``seeds``, appending to ``folder/seeds.jsonl``; write the tables."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = folder / "seeds.jsonl"
    done = {}
    if lines.exists():
        for line in lines.read_text().splitlines():
            if line.strip():
                entry = json.loads(line)
                done[entry["seed"]] = entry
    results = []
    for seed in seeds:
        if seed not in done:
            done[seed] = run_seed(seed, log)
            with lines.open("a") as out:
                out.write(json.dumps(done[seed]) + "\n")
        results.append(done[seed])
    (folder / "report.md").write_text(report_tables(results))
    return results


def _max_pct(values: Sequence[float]) -> str:
    finite = [v for v in values if math.isfinite(v)]
    worst = max(finite) if finite else math.nan
    return f"{100 * worst:.1f}" + ("" if len(finite) == len(values) else " (non-finite)")


def report_tables(results: Sequence[dict[str, Any]]) -> str:
    """Return the markdown tables (one per quantity) of the seeds' results."""
    rows = ["## Structure drawn", "", "| seed | laws (joints 1-3) | cable | identify -> test |"]
    rows.append("|---|---|---|---|")
    for r in results:
        s = r["structure"]
        rows.append(
            f"| {r['seed']} | {', '.join(s['friction_laws'])} | {s['cable_form']} |"
            f" {s['identification_motion']} -> {s['test_motion']} |"
        )
    rows += ["", "## Identification: default (guarded) vs coupled CV, test motion (held out)", ""]
    rows += ["| seed | chosen | WN joints | fallbacks | default % | coupled CV % | worst gap |"]
    rows.append("|---|---|---|---|---|---|---|")
    gaps_all = []
    for r in results:
        d, c = np.array(r["default_test_rms"]), np.array(r["coupled_cv_test_rms"])
        gaps = 100 * (d - c)
        gaps_all.append(gaps)
        wn = r["guards"]["wn_joints"]
        kept = "-" if wn is None else ",".join(str(j + 1) for j, k in enumerate(wn) if k) or "none"
        rows.append(
            f"| {r['seed']} | {r['default_friction']} | {kept} |"
            f" {len(r['guards']['fallbacks'])} | {_pct(d)} | {_pct(c)} | {gaps.max():+.2f} |"
        )
    if gaps_all:
        mean_gap = np.mean(np.array(gaps_all), axis=0)
        worst = max(float(g.max()) for g in gaps_all)
        rows.append("")
        rows.append(
            f"Mean gap (default - CV) per joint: {' / '.join(f'{g:+.2f}' for g in mean_gap)}"
            f" points; worst {worst:+.2f} points."
        )
    rows += ["", "## Contact force (palpation, held out)", "", "| seed | error % of RMS force |"]
    rows.append("|---|---|")
    errors = [r["contact_error_pct"] for r in results]
    for r in results:
        rows.append(f"| {r['seed']} | {r['contact_error_pct']:.2f} |")
    if errors:
        rows.append("")
        rows.append(
            f"Median {np.median(errors):.2f} %, worst {max(errors):.2f} %,"
            f" {sum(e <= 7.0 for e in errors)} of {len(errors)} at most 7 %."
        )
    rows += ["", "## Residual loop (tested effects)", ""]
    rows += [
        "| seed | planted | named | false (effect session) | false (clean) |"
        " test before -> after, effect session % | worst reported % | fallbacks |"
    ]
    rows.append("|---|---|---|---|---|---|---|---|")
    named = clean_false = effect_false = 0
    for r in results:
        e, c = r["effect"], r["clean"]
        named += bool(e["named"])
        clean_false += bool(c["false_effects"])
        effect_false += bool(e["false_effects"])
        reported = e["before"] + e["after"] + c["before"] + c["after"]
        reported += e["test_before"] + e["test_after"] + c["test_before"] + c["test_after"]
        fallbacks = len(e["fallbacks"]) + len(c["fallbacks"])
        rows.append(
            f"| {r['seed']} | {e['effect']} | {'yes' if e['named'] else 'no'} |"
            f" {'; '.join(e['false_effects']) or '-'} | {'; '.join(c['false_effects']) or '-'} |"
            f" {_pct(e['test_before'])} -> {_pct(e['test_after'])} | {_max_pct(reported)} |"
            f" {fallbacks} |"
        )
    n = len(results)
    rows.append("")
    rows.append(
        f"Named {named} of {n}; false effects in {clean_false} of {n} clean sessions and"
        f" {effect_false} of {n} effect sessions."
    )
    return "\n".join(rows) + "\n"
