"""Blind tests of the residual loop on simulated data with an undeclared effect switched on.

For every effect family the simulated plant can switch on (and for clean data), simulate a
session, give it to :func:`~teleop_force.residual.loop.trace_residual` without saying anything,
and check the first effect found names the right joint and variable. Writes a markdown table
(``teleop-force residual-blind -o DIR``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from time import perf_counter
from typing import Any

from teleop_force.io.interchange_csv import Recording
from teleop_force.residual.loop import trace_residual
from teleop_force.residual.options import ResidualOptions
from teleop_force.robots.omni import omni_description
from teleop_force.simulation import EFFECT_NAMES, make_effect, rigid_body_protocol

#: What a correct trace names for each plant effect: (joint 1-based, acceptable variables).
EXPECTED: dict[str, tuple[int, tuple[str, ...]]] = {
    "cogging": (1, ("q1",)),
    "position-friction": (2, ("q2",)),
    "drifting-friction": (1, ("t",)),
    "load-friction": (2, ("tau2",)),
    "elbow-bump": (3, ("q2-q3", "q3-q2")),
    "cross-direction-offset": (3, ("qd1",)),
}

#: Plant effects the declared model already contains, so the correct trace adds nothing: the
#: effect's joint and why. A direction-dependent offset of a joint's own motion,
#: ``offset (1 + sgn(qd_j)) / 2``, is a constant plus a Coulomb term, and the friction
#: model (the wavelet network over the joint's velocities, or CV with offsets) has both.
DECLARED: dict[str, tuple[int, str]] = {
    "direction-offset": (
        3,
        "a constant plus Coulomb friction of q̇3: already in the friction model",
    ),
}


@dataclass(frozen=True)
class BlindCase:
    """Result of one blind test."""

    effect: str
    expected_joint: int | None
    expected_variables: tuple[str, ...]
    found: tuple[dict[str, Any], ...]
    before: tuple[float, ...]
    after: tuple[float, ...]
    history: tuple[dict[str, Any], ...] = ()
    strongest_rejected: dict[str, Any] | None = None

    @property
    def passed(self) -> bool:
        """Clean or declared: nothing found; else the first effect names joint and variable."""
        if self.expected_joint is None:
            return not self.found
        if not self.found:
            return False
        first = self.found[0]
        variables = {first["variable"], *first["depends_on"]}
        if first["kind"] in ("offset", "direction-dependent offset"):
            variables.add("offset")
        joint_ok = first["joint"] == self.expected_joint
        cut = self.after[self.expected_joint - 1] < self.before[self.expected_joint - 1]
        return bool(joint_ok and variables & set(self.expected_variables) and cut)


def run_blind_tests(
    duration_s: float = 60.0,
    effects: tuple[str, ...] = ("clean", *EFFECT_NAMES),
    seed: int = 5,
    log: Callable[[str], None] = print,
) -> list[BlindCase]:
    """Simulate and trace every case."""
    description = omni_description()
    cases = []
    for name in effects:
        started = perf_counter()
        plant_effects = () if name == "clean" else (make_effect(name),)
        session = rigid_body_protocol(duration_s, seed, effects=plant_effects)
        recording = Recording(session.t_s, session.q_rad, session.tau_nm)
        report = trace_residual([recording], description)
        found = tuple({**e.to_json(), "variable": e.spec.variable} for e in report.effects)
        joint, variables = EXPECTED.get(name, (None, ()))  # clean and DECLARED: nothing
        case = BlindCase(
            name,
            joint,
            variables,
            found,
            tuple(report.before),
            tuple(report.after),
            tuple(report.history),
            max(report.rejected, key=lambda r: r["gain"], default=None),
        )
        log(
            f"{name}: {'PASS' if case.passed else 'FAIL'} in {perf_counter() - started:.0f} s;"
            f" found {[f['description'] for f in found]}"
        )
        cases.append(case)
    return cases


def _json_default(value: Any) -> Any:
    """NumPy scalars and arrays, and tuples of them, as JSON values."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return list(value)


def write_blind_report(cases: list[BlindCase], folder: Path) -> Path:
    """Write ``blind.md`` and ``blind.json`` into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Residual loop: blind tests on simulated data",
        "",
        "Each session: the rigid-body protocol of IV-A (4 sinusoids per joint, 0.5-2 Hz),"
        " one undeclared effect switched on",
        "in the plant; the tool is told nothing. Held-out relative RMS of the effect's joint.",
        "",
        "| plant effect | named joint | depends on | kind | joint before | joint after |"
        " gain (over the friction controls) | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for c in cases:
        declared = DECLARED.get(c.effect)
        if declared is not None:
            notes.append(f"- `{c.effect}`: expected nothing added ({declared[1]}).")
        j = (c.expected_joint or (declared[0] if declared else 1)) - 1
        if c.found:
            f = c.found[0]
            named = (f"{f['joint']}", ", ".join(f["depends_on"]) or "-", f["kind"])
        else:
            named = ("-", "-", "nothing added")
        joint = c.expected_joint or (declared[0] if declared else 0)
        before = c.before[j] if joint else min(c.before)
        after = c.after[j] if joint else min(c.after)
        label = f"joint {joint}" if joint else "all joints (min)"
        gains = (
            f"{c.history[0]['gain']:.1%} ({c.history[0]['control_gain']:.1%})" if c.history else "-"
        )
        lines.append(
            f"| {c.effect} | {named[0]} | {named[1]} | {named[2]} | {before:.2%} ({label}) |"
            f" {after:.2%} | {gains} | {'PASS' if c.passed else 'FAIL'} |"
        )
    for c in cases:
        r = c.strongest_rejected
        if r is not None and not c.found:
            notes.append(
                f"- `{c.effect}`: strongest candidate rejected by the friction controls:"
                f" {r['effect']}, held-out gain {r['gain']:.1%}, over the controls"
                f" {r['control_gain']:.1%} (threshold {ResidualOptions().min_control_gain:.0%})."
            )
    if notes:
        lines += ["", *notes]
    (folder / "blind.md").write_text("\n".join(lines) + "\n")
    (folder / "blind.json").write_text(
        json.dumps(
            [c.__dict__ | {"passed": c.passed} for c in cases], indent=1, default=_json_default
        )
    )
    return folder / "blind.md"
