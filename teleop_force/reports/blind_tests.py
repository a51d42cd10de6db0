"""Blind tests of the residual loop on simulated data with an undeclared effect switched on.

For both simulated plant families (``one``: the project's plant, the model's own friction
shape; ``two``: another plant, LuGre friction, other masses, noise and quantization, so the
baseline friction's shape is wrong), for every effect the plant can switch on and for clean
data, simulate a session, give it to :func:`~teleop_force.residual.loop.trace_residual`
without saying anything, and check what it names:

- **named**: one of the found effects names the planted effect's joint, variable and kind,
  and the joint's held-out error falls;
- **false effects**: found effects that are neither the planted effect nor a correction of a
  joint's own friction shape (a function of the joint's own velocity, a Stribeck shape or a
  direction-dependent offset: the baseline friction's shape, fair to name on a plant whose
  friction is not the model's). They must be 0 in every session, clean ones included; the
  friction-shape corrections are listed apart.

Then the loop from a model in hand (:func:`~teleop_force.residual.from_model.trace_from_model`)
on a session with a planted payload (a tip mass), the model identified on a clean session of
the same family. Writes a markdown table (``teleop-force residual-blind -o DIR``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from time import perf_counter
from typing import Any

from teleop_force.io.interchange_csv import Recording
from teleop_force.residual.loop import trace_residual
from teleop_force.residual.options import ResidualOptions
from teleop_force.robots.omni import omni_description
from teleop_force.simulation import EFFECT_NAMES, SessionOptions, make_effect, rigid_body_protocol

#: What a correct trace names for each plant effect: joint (1-based), acceptable variables,
#: acceptable kinds.
EXPECTED: dict[str, tuple[int, tuple[str, ...], tuple[str, ...]]] = {
    "cogging": (1, ("q1",), ("position-periodic torque", "position-dependent torque")),
    "position-friction": (
        2,
        ("q2",),
        ("position-dependent friction", "position-dependent torque, direction-dependent part"),
    ),
    "drifting-friction": (1, ("t",), ("friction drift",)),
    "load-friction": (2, ("tau2",), ("load-dependent friction",)),
    "elbow-bump": (
        3,
        ("q2-q3", "q3-q2"),
        ("position-dependent torque", "position-periodic torque"),
    ),
    "cross-direction-offset": (3, ("qd1",), ("cross-joint coupling",)),
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

#: The simulated plant families the table covers.
FAMILIES: tuple[str, ...] = ("one", "two")
#: Tip mass of the payload case [kg].
PAYLOAD_KG = 0.05


def is_friction_shape(found: dict[str, Any]) -> bool:
    """Whether a found effect corrects its joint's own friction shape (not a false effect)."""
    own = f"qd{found['joint']}"
    if found["kind"] in ("stribeck friction", "velocity-dependent friction"):
        return True
    if found["kind"] == "direction-dependent offset":
        return True
    return bool(found.get("variable") == own)


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
    expected_kinds: tuple[str, ...] = ()
    family: str = "one"

    def _matches(self, found: dict[str, Any]) -> bool:
        """Whether ``found`` names the planted effect's joint, variable and kind."""
        variables = {found.get("variable", ""), *found["depends_on"]}
        kind_ok = not self.expected_kinds or found["kind"] in self.expected_kinds
        return bool(
            found["joint"] == self.expected_joint
            and variables & set(self.expected_variables)
            and kind_ok
        )

    @property
    def named(self) -> dict[str, Any] | None:
        """The first found effect that names the planted effect (None: none does)."""
        if self.expected_joint is None:
            return None
        return next((f for f in self.found if self._matches(f)), None)

    @property
    def false_effects(self) -> tuple[dict[str, Any], ...]:
        """Found effects that are neither the planted one nor a friction-shape correction."""
        return tuple(
            f
            for f in self.found
            if not (self.expected_joint is not None and self._matches(f))
            and not is_friction_shape(f)
        )

    @property
    def friction_shapes(self) -> tuple[dict[str, Any], ...]:
        """Found corrections of a joint's own friction shape (fair, listed apart)."""
        return tuple(f for f in self.found if is_friction_shape(f) and f not in self.named_all)

    @property
    def named_all(self) -> tuple[dict[str, Any], ...]:
        """Every found effect that names the planted effect."""
        if self.expected_joint is None:
            return ()
        return tuple(f for f in self.found if self._matches(f))

    @property
    def passed(self) -> bool:
        """No false effect; and for a planted effect, named with its joint's error cut."""
        if self.false_effects:
            return False
        if self.expected_joint is None:
            return True
        j = self.expected_joint - 1
        return self.named is not None and self.after[j] < self.before[j]


@dataclass(frozen=True)
class PayloadCase:
    """The loop from a model in hand on a session with a planted tip mass."""

    family: str
    mass_kg: float
    found: tuple[dict[str, Any], ...]
    before: tuple[float, ...]
    after: tuple[float, ...]
    #: Relative RMS per joint on a third session with the payload: given, extended model.
    test_before: tuple[float, ...] = ()
    test_after: tuple[float, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """The first effect named is the payload, and no effect names a pose or time."""
        if not self.found or self.found[0]["kind"] != "payload":
            return False
        return all(f["kind"] == "payload" or is_friction_shape(f) for f in self.found)


def protocol_kwargs(family: str, tip_mass_kg: float = 0.0) -> SessionOptions:
    """Keyword arguments of the protocol builders for ``family`` and a tip mass."""
    kwargs: SessionOptions = {"family": family}
    if tip_mass_kg:
        kwargs["tip_mass_kg"] = tip_mass_kg
    return kwargs


def _recording(
    duration_s: float,
    seed: int,
    family: str,
    effect: str,
    mass: float = 0.0,
    arm: int | None = None,
) -> Recording:
    """Simulate the rigid-body protocol of ``family`` with ``effect`` (``clean``: none).

    ``arm``: family two's arm (its inertias and friction; default: the session's seed).
    """
    kwargs = protocol_kwargs(family, mass)
    kwargs["effects"] = () if effect == "clean" else (make_effect(effect),)
    if arm is not None and family == "two":
        from teleop_force.simulation import PlantTwoConfig

        kwargs["plant_config"] = PlantTwoConfig(instance_seed=arm)
    session = rigid_body_protocol(duration_s, seed, **kwargs)
    return Recording(session.t_s, session.q_rad, session.tau_nm)


def run_blind_tests(
    duration_s: float = 60.0,
    effects: tuple[str, ...] = ("clean", *EFFECT_NAMES),
    seed: int = 5,
    log: Callable[[str], None] = print,
    family: str = "one",
) -> list[BlindCase]:
    """Simulate and trace every case of one plant family."""
    description = omni_description()
    cases = []
    for name in effects:
        started = perf_counter()
        recording = _recording(duration_s, seed, family, name)
        report = trace_residual([recording], description)
        found = tuple({**e.to_json(), "variable": e.spec.variable} for e in report.effects)
        joint, variables, kinds = EXPECTED.get(name, (None, (), ()))
        case = BlindCase(
            name,
            joint,
            variables,
            found,
            tuple(report.before),
            tuple(report.after),
            tuple(report.history),
            max(report.rejected, key=lambda r: r["gain"], default=None),
            kinds,
            family,
        )
        log(
            f"family {family}, {name}: {'PASS' if case.passed else 'FAIL'} in"
            f" {perf_counter() - started:.0f} s; found {[f['description'] for f in found]}"
        )
        cases.append(case)
    return cases


def run_payload_case(
    family: str = "one",
    duration_s: float = 60.0,
    seed: int = 5,
    mass_kg: float = PAYLOAD_KG,
    log: Callable[[str], None] = print,
) -> PayloadCase:
    """Identify on a clean session, trace a session with a tip mass against that model.

    The three sessions (the model's, the traced one, the test) are of one arm, with
    different trajectories and noise.
    """
    from teleop_force.identification.pipeline import evaluate_model, identify_model
    from teleop_force.residual.from_model import trace_from_model

    started = perf_counter()
    description = omni_description()
    # one arm for the three sessions (family two picks an arm per seed otherwise)
    clean = _recording(duration_s, seed + 100, family, "clean", arm=seed)
    model, _ = identify_model([clean], description)
    loaded = _recording(duration_s, seed, family, "clean", mass_kg, arm=seed)
    report = trace_from_model([loaded], model, model_path=f"<clean session, family {family}>")
    test = [_recording(duration_s, seed + 200, family, "clean", mass_kg, arm=seed)]
    case = PayloadCase(
        family,
        mass_kg,
        tuple(_with_variables(report)),
        tuple(report.before),
        tuple(report.after),
        tuple(float(x) for x in evaluate_model(model, test)["relative_rms"]),
        tuple(float(x) for x in evaluate_model(report.model, test)["relative_rms"]),
    )
    log(
        f"family {family}, payload {mass_kg} kg: {'PASS' if case.passed else 'FAIL'} in"
        f" {perf_counter() - started:.0f} s; found {[f['description'] for f in case.found]}"
    )
    return case


def _with_variables(report: Any) -> list[dict[str, Any]]:
    """Return the report's JSON effects, each with its variable (the payload has none)."""
    out = []
    payload = [] if report.payload is None else [report.payload.to_json()]
    out += payload
    out += [{**e.to_json(), "variable": e.spec.variable} for e in report.effects]
    return out


def _json_default(value: Any) -> Any:
    """NumPy scalars and arrays, and tuples of them, as JSON values."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return list(value)


def _percent(values: tuple[float, ...]) -> str:
    return " / ".join(f"{100 * v:.2f}" for v in values)


def write_blind_report(
    cases: list[BlindCase], folder: Path, payloads: list[PayloadCase] | None = None
) -> Path:
    """Write ``blind.md`` and ``blind.json`` into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Residual loop: blind tests on simulated data",
        "",
        "Each session: the rigid-body protocol of IV-A (4 sinusoids per joint, 0.5-2 Hz),"
        " one undeclared effect switched on",
        "in the plant; the tool is told nothing. Held-out relative RMS of the effect's joint."
        " Family one: the project's plant; family two: LuGre friction, other masses, noise"
        " and quantization (the baseline friction's shape is wrong).",
        "",
        "| family | plant effect | named joint | depends on | kind | joint before | joint after |"
        " gain (over the friction controls) | false effects | friction-shape corrections"
        " | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for c in cases:
        declared = DECLARED.get(c.effect)
        if declared is not None and c.family == cases[0].family:
            notes.append(f"- `{c.effect}`: expected nothing added ({declared[1]}).")
        j = (c.expected_joint or (declared[0] if declared else 1)) - 1
        shown = c.named or (c.found[0] if c.found else None)
        if shown is not None:
            named = (f"{shown['joint']}", ", ".join(shown["depends_on"]) or "-", shown["kind"])
        else:
            named = ("-", "-", "nothing added")
        joint = c.expected_joint or (declared[0] if declared else 0)
        before = c.before[j] if joint else min(c.before)
        after = c.after[j] if joint else min(c.after)
        label = f"joint {joint}" if joint else "all joints (min)"
        gains = (
            f"{c.history[0]['gain']:.1%} ({c.history[0]['control_gain']:.1%})" if c.history else "-"
        )
        false = "; ".join(f["description"] for f in c.false_effects) or "0"
        shapes = "; ".join(f["description"] for f in c.friction_shapes) or "-"
        lines.append(
            f"| {c.family} | {c.effect} | {named[0]} | {named[1]} | {named[2]} |"
            f" {before:.2%} ({label}) | {after:.2%} | {gains} | {false} | {shapes} |"
            f" {'PASS' if c.passed else 'FAIL'} |"
        )
    for c in cases:
        r = c.strongest_rejected
        if r is not None and not c.found and "control_gain" in r:
            notes.append(
                f"- family {c.family}, `{c.effect}`: strongest candidate rejected:"
                f" {r['effect']}, held-out gain {r['gain']:.1%}, over the controls"
                f" {r['control_gain']:.1%} (threshold {ResidualOptions().min_control_gain:.0%})."
            )
    lines += ["", "Summary per family (planted effects named; sessions with a false effect):", ""]
    for family in dict.fromkeys(c.family for c in cases):
        mine = [c for c in cases if c.family == family]
        planted = [c for c in mine if c.expected_joint is not None]
        n_named = sum(c.named is not None for c in planted)
        n_false = sum(bool(c.false_effects) for c in mine)
        lines.append(
            f"- family {family}: {n_named} of {len(planted)} planted effects named"
            f" ({n_named / max(len(planted), 1):.0%}); false effects in {n_false} of"
            f" {len(mine)} sessions."
        )
    if payloads:
        lines += [
            "",
            "## A payload against a model in hand (`residual DATA --model MODEL`)",
            "",
            "Model identified (library defaults) on a clean session; DATA: a session with a"
            " tip mass. Relative RMS per joint [%], joints 1 / 2 / 3: on DATA (before: the"
            " model as given; after: held-out blocks) and on a third session with the same"
            " mass (given model, extended model).",
            "",
            "| family | tip mass | named | DATA before | DATA after | third session, given"
            " | extended | verdict |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for p in payloads:
            named_text = "; ".join(
                f"{f['kind']} (joints {f.get('joints', [f['joint']])}, depends on"
                f" {', '.join(f['depends_on'])})"
                for f in p.found
            )
            lines.append(
                f"| {p.family} | {p.mass_kg} kg | {named_text or 'nothing'} |"
                f" {_percent(p.before)} | {_percent(p.after)} | {_percent(p.test_before)} |"
                f" {_percent(p.test_after)} | {'PASS' if p.passed else 'FAIL'} |"
            )
    if notes:
        lines += ["", *notes]
    (folder / "blind.md").write_text("\n".join(lines) + "\n")
    payload_json = [p.__dict__ | {"passed": p.passed} for p in payloads or []]
    (folder / "blind.json").write_text(
        json.dumps(
            {
                "cases": [
                    c.__dict__
                    | {
                        "passed": c.passed,
                        "named": c.named,
                        "false_effects": list(c.false_effects),
                    }
                    for c in cases
                ],
                "payload": payload_json,
            },
            indent=1,
            default=_json_default,
        )
    )
    return folder / "blind.md"
