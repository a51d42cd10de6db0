import pytest

from teleop_force.cli.main import main
from teleop_force.errors import ConfigurationError
from teleop_force.reports.generated import _is_cable_friction, parse_seeds, report_tables
from teleop_force.simulation.generator import draw_plant


def _result(seed: int, default: list[float], cv: list[float], named: bool) -> dict:
    loop = {
        "before": [0.3, 0.2, 0.1], "after": [0.3, 0.2, 0.1],
        "test_before": [0.3, 0.2, 0.1], "test_after": [0.25, 0.2, 0.1],
        "fallbacks": [], "false_effects": [],
    }  # fmt: skip
    return {
        "seed": seed,
        "structure": {
            "friction_laws": ["dahl", "lugre", "stribeck"],
            "cable_form": "none",
            "identification_motion": "multi-sine",
            "test_motion": "teleoperation",
        },
        "default_friction": "wn",
        "guards": {"wn_joints": [True, False, True], "fallbacks": []},
        "default_test_rms": default,
        "coupled_cv_test_rms": cv,
        "contact_error_pct": 5.0 + seed,
        "clean": {**loop, "effect": "clean", "named": False},
        "effect": {**loop, "effect": "cogging", "named": named},
    }


def test_parse_seeds() -> None:
    assert parse_seeds("1-3,7") == (1, 2, 3, 7)
    for bad in ("", "a-b", "-1"):
        with pytest.raises(ConfigurationError):
            parse_seeds(bad)


def test_report_tables_count_what_they_say() -> None:
    results = [
        _result(1, [0.20, 0.10, 0.10], [0.21, 0.10, 0.10], True),
        _result(2, [0.30, 0.12, 0.10], [0.20, 0.10, 0.10], False),
    ]
    text = report_tables(results)
    assert "| 1 | dahl, lugre, stribeck | none | multi-sine -> teleoperation |" in text
    assert "| 2 | wn | 1,3 | 0 | 30.0 / 12.0 / 10.0 | 20.0 / 10.0 / 10.0 | +10.00 |" in text
    assert "worst +10.00 points" in text
    assert "Median 6.50 %, worst 7.00 %, 2 of 2 at most 7 %." in text
    assert "Named 1 of 2; false effects in 0 of 2 clean sessions" in text


def test_cli_needs_exactly_one_seed_source(tmp_path, capsys) -> None:
    assert main(["generated-report", "-o", str(tmp_path)]) == 2
    assert main(["generated-report", "--seeds", "1", "--reported", "x", "-o", str(tmp_path)]) == 2
    assert main(["generated-report", "--reported", "abc", "-o", str(tmp_path)]) == 2
    assert "commit id" in capsys.readouterr().err


def test_the_drawn_cable_is_not_a_false_effect() -> None:
    with_cable = next(p for p in map(draw_plant, range(50)) if p.cable_form != "none")
    without = next(p for p in map(draw_plant, range(50)) if p.cable_form == "none")
    cable = {"joint": 2, "depends_on": ["qd3"]}
    assert _is_cable_friction(with_cable, cable) and not _is_cable_friction(without, cable)
    assert not _is_cable_friction(with_cable, {"joint": 3, "depends_on": ["q1", "q2"]})
    assert not _is_cable_friction(with_cable, {"joint": 1, "depends_on": ["qd2"]})
