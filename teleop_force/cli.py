"""The ``teleop-force`` command line (see ../shared/CONTRACT.md).

Exit status 0 on success, 2 for bad usage or unreadable input with one line on stderr naming
the file, row or field. ``--json`` output is a single JSON object on stdout; logs go to stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from teleop_force.errors import TeleopForceError

EXIT_OK = 0
EXIT_BAD_INPUT = 2


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _load_recordings(paths: Sequence[str], n_joints: int | None = None) -> list[Any]:
    from teleop_force.recordings import read_recording

    return [read_recording(Path(p), n_joints=n_joints) for p in paths]


def _cmd_identify(args: argparse.Namespace) -> int:
    from teleop_force.model_fitting import WaveletOptions, identify_model
    from teleop_force.robots import resolve_robot

    recordings = _load_recordings(args.data)
    n = recordings[0].q_rad.shape[1]
    description = resolve_robot(args.robot, n)
    model, report = identify_model(
        recordings, description, args.friction, wavelet=WaveletOptions(method=args.wn_fit)
    )
    model.save(args.output)
    _log(report.rigid.table())
    _log("training relative RMS per joint: " + ", ".join(f"{x:.2%}" for x in report.friction_relative_rms))
    for key, value in report.details.items():
        _log(f"{key}: {value}")
    _log(f"model written to {args.output}")
    return EXIT_OK


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from teleop_force.dynamic_model import DynamicModel
    from teleop_force.model_fitting import evaluate_model

    model = DynamicModel.load(args.model)
    recordings = _load_recordings(args.data, model.n_joints)
    result = evaluate_model(model, recordings)
    payload = {
        "relative_rms": [float(x) for x in result["relative_rms"]],
        "samples": result["samples"],
        "coverage": [float(x) for x in result["coverage"]],
        "friction": model.friction.kind,
        "robot": model.robot,
    }
    if args.json:
        print(json.dumps(payload))
    else:
        for j, value in enumerate(payload["relative_rms"]):
            print(f"joint {j + 1}: relative RMS {value:.2%}, on trained ground {payload['coverage'][j]:.0%}")
        print(f"samples: {payload['samples']}")
    return EXIT_OK


def _cmd_estimate(args: argparse.Namespace) -> int:
    from teleop_force.dynamic_model import DynamicModel
    from teleop_force.estimation import ForceEstimator

    model = DynamicModel.load(args.model)
    (recording,) = _load_recordings([args.data], model.n_joints)
    estimator = ForceEstimator(model)
    forces = np.empty((recording.t_s.size, 3))
    for k in range(recording.t_s.size):
        forces[k] = estimator.update(recording.t_s[k], recording.q_rad[k], recording.tau_nm[k]).force_tip_in_base_n
    table = np.column_stack((recording.t_s, forces))
    np.savetxt(args.output, table, delimiter=",", header="t,f_x,f_y,f_z", comments="", fmt="%.9g")
    _log(f"{recording.t_s.size} estimates written to {args.output}")
    return EXIT_OK


def _cmd_residual(args: argparse.Namespace) -> int:
    from teleop_force.residual import ResidualOptions, trace_residual
    from teleop_force.residual_report import write_residual_report
    from teleop_force.robots import resolve_robot

    recordings = _load_recordings(args.data)
    description = resolve_robot(args.robot, recordings[0].q_rad.shape[1])
    report = trace_residual(recordings, description, ResidualOptions(friction=args.friction))
    if args.output:
        path = write_residual_report(report, Path(args.output), list(description.joint_names))
        _log(f"report written to {path}")
    if args.json:
        print(json.dumps(report.to_json()))
    else:
        for j in range(report.before.size):
            print(f"joint {j + 1}: held-out relative RMS {report.before[j]:.2%} -> {report.after[j]:.2%}")
        for effect in report.effects:
            e = effect.to_json()
            print(f"  + {e['description']}: {e['kind']}, explains {e['explained']:.1%} of joint {e['joint']}'s residual")
        if not report.effects:
            print("no significant effect found")
    return EXIT_OK


def _not_yet(name: str) -> Callable[[argparse.Namespace], int]:
    def run(args: argparse.Namespace) -> int:
        _log(f"teleop-force {name}: not implemented yet")
        return 1

    return run


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``teleop-force``."""
    parser = argparse.ArgumentParser(prog="teleop-force", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("identify", help="identify rigid-body parameters and friction")
    p.add_argument("data", nargs="+", help="recordings (.csv interchange or .mcap session)")
    p.add_argument("--robot", default="omni", help="omni (default), none, or a description file")
    p.add_argument("--friction", choices=("cv", "coupled-cv", "wn"), default="wn")
    p.add_argument("--wn-fit", choices=("adaptive", "batch"), default="adaptive",
                   help="train the wavelet network by Lyapunov adaptation (paper) or batch least squares")
    p.add_argument("-o", "--output", required=True, help="model file to write (JSON)")
    p.set_defaults(run=_cmd_identify)

    p = sub.add_parser("evaluate", help="reverse torque computation, relative RMS per joint")
    p.add_argument("model")
    p.add_argument("data", nargs="+")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_cmd_evaluate)

    p = sub.add_parser("estimate", help="contact-force estimate for every sample")
    p.add_argument("model")
    p.add_argument("data")
    p.add_argument("-o", "--output", required=True)
    p.set_defaults(run=_cmd_estimate)

    p = sub.add_parser("residual", help="find, trace and add what the model lacks; report before/after")
    p.add_argument("data", nargs="+")
    p.add_argument("--robot", default="omni")
    p.add_argument("--friction", choices=("cv", "coupled-cv"), default="coupled-cv",
                   help="friction of the model the residual is taken from")
    p.add_argument("--json", action="store_true")
    p.add_argument("-o", "--output", help="folder for the report (markdown, plots, model.json)")
    p.set_defaults(run=_cmd_residual)

    for name in ("demo", "replay", "bench"):
        p = sub.add_parser(name)
        p.set_defaults(run=_not_yet(name))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args))
    except TeleopForceError as exc:
        _log(f"teleop-force {args.command}: {exc}")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
