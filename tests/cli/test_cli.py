import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from teleop_force.cli.main import main
from teleop_force.io.interchange_csv import Recording, write_interchange_csv
from teleop_force.simulation import rigid_body_protocol, teleoperation_protocol


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    train = rigid_body_protocol(12.0, seed=2)
    test = teleoperation_protocol(6.0, seed=3)
    paths = []
    for name, s in (("train.csv", train), ("test.csv", test)):
        path = folder / name
        write_interchange_csv(path, Recording(s.t_s, s.q_rad, s.tau_nm, s.f_tip_in_base_n))
        paths.append(path)
    return folder, paths[0], paths[1]


def test_identify_then_evaluate_and_estimate(sessions, capsys) -> None:
    folder, train, test = sessions
    model = folder / "model.json"
    assert main(["identify", str(train), "--friction", "coupled-cv", "-o", str(model)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(model), str(test), "--json"]) == 0
    out = capsys.readouterr().out
    payload = json.loads(out)
    assert len(payload["relative_rms"]) == 3
    assert all(0.0 < r < 1.0 for r in payload["relative_rms"])
    assert payload["samples"] > 1000
    forces = folder / "forces.csv"
    assert main(["estimate", str(model), str(test), "-o", str(forces)]) == 0
    table = np.loadtxt(forces, delimiter=",", skiprows=1)
    assert forces.read_text().splitlines()[0] == "t,f_x,f_y,f_z"
    assert table.shape[1] == 4


def test_identify_wn_is_the_default_and_round_trips(sessions, capsys) -> None:
    folder, train, test = sessions
    model = folder / "wn.json"
    assert main(["identify", str(train), "-o", str(model)]) == 0
    saved = json.loads(model.read_text())
    assert saved["friction"]["kind"] == "wn"
    # the Omni's identification looks for a sticking state and says what it kept
    assert "sticking transition angle:" in capsys.readouterr().err
    # and estimates on its count observer's angles, with the counts measured on the data
    assert saved["filter"]["count_observer"] is True
    np.testing.assert_allclose(saved["filter"]["count_rad"], [4e-4] * 3, rtol=1e-9)
    assert saved["filter"]["observer_hz"] == 400.0
    assert (
        main(["identify", str(train), "--no-sticking", "--no-count-observer", "-o", str(model)])
        == 0
    )
    err = capsys.readouterr().err
    assert "sticking" not in err and "count observer" not in err
    assert "count_observer" not in json.loads(model.read_text())["filter"]
    capsys.readouterr()
    assert main(["evaluate", str(model), str(test), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert len(payload["coverage"]) == 3
    assert payload["count_observer"] is False  # identified with --no-count-observer


BAD_FILES = {
    "missing_column.csv": ("t,q1,q2,q3,tau1,tau2\n0,0,0,0,0,0\n", "tau3"),
    "non_numeric.csv": ("t,q1,q2,q3,tau1,tau2,tau3\n0,0,0,0,0,0,0\n0.001,0,abc,0,0,0,0\n", "row 3"),
    "nan.csv": ("t,q1,q2,q3,tau1,tau2,tau3\n0,0,0,0,0,0,0\n0.001,0,0,nan,0,0,0\n", "row 3"),
    "time.csv": (
        "t,q1,q2,q3,tau1,tau2,tau3\n0,0,0,0,0,0,0\n0.001,0,0,0,0,0,0\n0.001,0,0,0,0,0,0\n",
        "row 4",
    ),
    "empty.csv": ("", "empty"),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_input_exits_2_with_one_clear_line(tmp_path: Path, capsys, name: str) -> None:
    text, expected = BAD_FILES[name]
    path = tmp_path / name
    path.write_text(text)
    assert main(["identify", str(path), "-o", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert str(path) in err[0]
    assert expected.lower() in err[0].lower()
    assert "Traceback" not in err[0]


def test_bad_model_file_names_the_field(tmp_path: Path, sessions, capsys) -> None:
    _, _, test = sessions
    model = tmp_path / "broken.json"
    model.write_text(
        json.dumps({"format": "teleop-force-model", "version": 1, "robot": "omni", "n_joints": 3})
    )
    assert main(["evaluate", str(model), str(test)]) == 2
    err = capsys.readouterr().err
    assert "broken.json" in err and "filter" in err


def test_console_script_reports_without_traceback(tmp_path: Path) -> None:
    path = tmp_path / "x.csv"
    path.write_text("t,q1\n")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "teleop_force.cli.main",
            "identify",
            str(path),
            "-o",
            str(tmp_path / "m.json"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_residual_choices_are_the_libraries_own() -> None:
    """The parser lists the residual choices from the library's enums, and each is accepted."""
    from teleop_force.cli.main import build_parser
    from teleop_force.friction.kinds import FrictionKind
    from teleop_force.residual.options import EffectPlacement, ResidualOptions

    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "residual" in a.choices)
    residual = sub.choices["residual"]
    choices = {a.dest: tuple(a.choices) for a in residual._actions if a.choices}
    assert choices["effect_placement"] == ("auto", "motor", "model", "either")
    assert choices["friction"] == ("cv", "coupled-cv", "model-cv", "wn")  # the contract's flags
    for placement in choices["effect_placement"]:
        assert ResidualOptions(effect_placement=placement).effect_placement is EffectPlacement(
            placement
        )
    for kind in choices["friction"]:
        assert ResidualOptions(friction=kind).friction is FrictionKind(kind)


def test_demo_zenoh_flags_are_a_port_only(capsys) -> None:
    """ROS 2 is the demo's only live format and it always has a router: no --ros2, no --router."""
    from teleop_force.cli.main import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "demo" in a.choices)
    flags = {o for a in sub.choices["demo"]._actions for o in a.option_strings}
    assert "--zenoh-port" in flags and not flags & {"--ros2", "--router"}
    for gone in ("--ros2", "--router"):
        with pytest.raises(SystemExit) as exit_info:
            main(["demo", gone])
        assert exit_info.value.code == 2
        assert f"unrecognized arguments: {gone}" in capsys.readouterr().err
    args = parser.parse_args(["demo", "--zenoh-port", "7450"])
    assert args.zenoh_port == 7450


def test_building_the_parser_does_not_import_the_residual_loop() -> None:
    """The choices come from the light options module, not the loop (SciPy fits, numba)."""
    code = (
        "import sys; from teleop_force.cli.main import build_parser; build_parser();"
        " print(sorted(m for m in sys.modules if m.startswith('teleop_force.residual')));"
        " print(sorted(m for m in ('numba', 'scipy', 'pinocchio') if m in sys.modules))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    residual, heavy = done.stdout.strip().splitlines()
    assert residual == "['teleop_force.residual', 'teleop_force.residual.options']"
    assert heavy == "[]"


def test_export_json_rewrites_a_cdr_session_with_json_channels(tmp_path, capsys):
    from teleop_force.io.mcap_session import SessionReader, SessionWriter
    from teleop_force.transport import keys
    from teleop_force.transport import messages as m

    source, target = tmp_path / "cdr.mcap", tmp_path / "json.mcap"
    with SessionWriter(source, {"primary_device": "slave"}) as writer:
        for k in range(20):
            js = m.JointState(k, 1000 + k, (0.1, 0.2, 0.3), (0.0,) * 3, (0.01 * k, 0.0, 0.0))
            writer.write(keys.measured_js("slave"), js, 1000 + k)
    assert main(["export-json", str(source), "-o", str(target), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["messages"] == 20 and out["skipped"] == 0
    exported = list(SessionReader(target).messages())
    original = list(SessionReader(source).messages())
    assert exported == original
    assert set(SessionReader(target).topics.values()) == {"teleop_force.JointState"}
