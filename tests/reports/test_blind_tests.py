"""Tests of teleop_force.reports.blind_tests: verdicts and the report (the runs are the CLI's)."""

import json
from pathlib import Path

from teleop_force.reports.blind_tests import (
    DECLARED,
    EXPECTED,
    BlindCase,
    protocol_kwargs,
    write_blind_report,
)
from teleop_force.simulation import EFFECT_NAMES

FOUND_Q2 = {
    "joint": 2, "depends_on": ["q2", "qd2"], "kind": "position-dependent torque",
    "description": "joint 2: smooth(q2) x sgn(qd2)", "variable": "q2",
}  # fmt: skip


def test_every_plant_effect_has_an_expectation() -> None:
    assert set(EFFECT_NAMES) == set(EXPECTED) | set(DECLARED)
    assert not set(EXPECTED) & set(DECLARED)


def test_protocol_arguments_name_the_family_and_payload() -> None:
    assert protocol_kwargs("two", 0.05) == {"family": "two", "tip_mass_kg": 0.05}
    assert protocol_kwargs("one") == {"family": "one"}


STRIBECK_3 = {
    "joint": 3, "depends_on": ["qd3"], "kind": "stribeck friction",
    "description": "joint 3: stribeck(qd3) x sgn(qd3)", "variable": "qd3",
}  # fmt: skip
POSE_3 = {
    "joint": 3, "depends_on": ["q1", "q3"], "kind": "position-dependent torque",
    "description": "joint 3: smooth(q1-q3)", "variable": "q1-q3",
}  # fmt: skip


def test_verdicts() -> None:
    before, after = (0.05, 0.06, 0.04), (0.05, 0.045, 0.04)
    right = BlindCase("position-friction", 2, ("q2",), (FOUND_Q2,), before, after)
    wrong_joint = BlindCase("position-friction", 3, ("q2",), (FOUND_Q2,), before, after)
    no_cut = BlindCase("position-friction", 2, ("q2",), (FOUND_Q2,), before, before)
    assert right.passed and not wrong_joint.passed and not no_cut.passed
    assert BlindCase("direction-offset", None, (), (), before, before).passed
    assert not BlindCase("clean", None, (), (FOUND_Q2,), before, after).passed


def test_the_kind_must_match_and_false_effects_fail_a_named_case() -> None:
    before, after = (0.05, 0.06, 0.04), (0.05, 0.045, 0.04)
    kinds = ("load-dependent friction",)
    wrong_kind = BlindCase("load-friction", 2, ("q2",), (FOUND_Q2,), before, after, (), None, kinds)
    assert wrong_kind.named is None and not wrong_kind.passed
    # named second, after a correction of joint 3's friction shape: named, no false effect
    later = BlindCase("position-friction", 2, ("q2",), (STRIBECK_3, FOUND_Q2), before, after)
    assert later.named == FOUND_Q2 and later.false_effects == () and later.passed
    assert later.friction_shapes == (STRIBECK_3,)
    # a pose effect nobody planted is a false effect, even beside the planted one
    extra = BlindCase("position-friction", 2, ("q2",), (FOUND_Q2, POSE_3), before, after)
    assert extra.false_effects == (POSE_3,) and not extra.passed
    assert BlindCase("clean", None, (), (STRIBECK_3,), before, after).passed


def test_report_names_declared_effects_and_rejections(tmp_path: Path) -> None:
    rejected = {"effect": "joint 2: smooth(q2)", "gain": 0.09, "control_gain": 0.042}
    history = ({"effect": "joint 2: smooth(q2) x sgn(qd2)", "gain": 0.30, "control_gain": 0.21},)
    cases = [
        BlindCase(
            "clean", None, (), (), (0.045, 0.042, 0.039), (0.045, 0.042, 0.039), (), rejected
        ),
        BlindCase("direction-offset", None, (), (), (0.045, 0.04, 0.041), (0.045, 0.04, 0.041)),
        BlindCase(
            "position-friction",
            2,
            ("q2",),
            (FOUND_Q2,),
            (0.046, 0.064, 0.039),
            (0.046, 0.044, 0.039),
            history,
        ),
    ]
    text = write_blind_report(cases, tmp_path).read_text()
    assert (
        "| one | direction-offset | - | - | nothing added | 4.10% (joint 3) | 4.10% | - | 0 | - |"
        " PASS |" in text
    )
    assert "30.0% (21.0%)" in text
    assert "`clean`: strongest candidate rejected" in text and "over the controls 4.2%" in text
    assert "`direction-offset`: expected nothing added" in text
    assert "family one: 1 of 1 planted effects named (100%); false effects in 0 of 3" in text
    saved = json.loads((tmp_path / "blind.json").read_text())
    assert [c["passed"] for c in saved["cases"]] == [True, True, True]
