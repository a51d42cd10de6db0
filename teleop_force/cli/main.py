"""The ``teleop-force`` command line (see docs/cli.md).

Exit status 0 on success, 2 for bad usage or unreadable input with one line on stderr naming
the file, row or field. ``--json`` output is a single JSON object on stdout; logs go to stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np

from teleop_force.errors import ConfigurationError, TeleopForceError
from teleop_force.estimation.flags import (
    add_estimator_arguments,
    forwarded_estimator_arguments,
    given_estimator_flags,
)
from teleop_force.transport.session import add_zenoh_arguments

EXIT_OK = 0
EXIT_BAD_INPUT = 2

#: What ``add_subparsers`` returns; each ``_add_<command>`` adds one subcommand to it.
_Subparsers: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _load_recordings(
    paths: Sequence[str],
    n_joints: int | None = None,
    robot: str | None = None,
    driver: str | None = None,
) -> list[Any]:
    """Read every DATA; ``driver`` (``--driver``): the sessions' joint states are its."""
    from teleop_force.io.recordings import read_recording_with_notes

    interface = None
    if driver is not None:
        from teleop_force.robots.registry import resolve_driver

        interface = resolve_driver(driver)
    recordings = []
    for p in paths:
        recording, notes = read_recording_with_notes(
            Path(p), n_joints=n_joints, robot=robot, driver=interface
        )
        for note in notes:
            _log(note)
        recordings.append(recording)
    return recordings


def _cmd_identify(args: argparse.Namespace) -> int:
    from teleop_force.friction.kinds import FrictionKind
    from teleop_force.identification.pipeline import identify_model
    from teleop_force.identification.prepared import wavelet_options_for
    from teleop_force.robots.kinds import RobotKind
    from teleop_force.robots.registry import resolve_robot, robot_defaults

    recordings = _load_recordings(args.data, robot=_reader_robot(args.robot), driver=args.driver)
    n = recordings[0].q_rad.shape[1]
    description = resolve_robot(args.robot, n)
    defaults = robot_defaults(args.robot)  # the robot's best baseline (docs/cli.md)
    friction = FrictionKind(args.friction or defaults.friction)
    if description.name == RobotKind.TESTSTAND:
        from teleop_force.estimation.teststand import identify_teststand_command

        if args.count_observer:
            raise ConfigurationError("identify --robot teststand takes no --count-observer")

        return identify_teststand_command(
            recordings, description, friction, args.output, _log, sticking=bool(args.sticking)
        )
    offsets = defaults.offsets if args.offsets is None else args.offsets
    sticking = defaults.sticking_with(friction) if args.sticking is None else args.sticking
    count_observer = defaults.count_observer if args.count_observer is None else args.count_observer
    options: dict[str, Any] = {
        "wavelet": wavelet_options_for(args.wn_structure, args.wn_fit),
        "offsets": offsets,
        "sticking": sticking,
        "count_observer": count_observer,
    }
    if args.guards:
        from teleop_force.identification.guards import identify_guarded

        model, report, guards = identify_guarded(recordings, description, friction, **options)
        for line in guards.lines():
            _log(line)
    else:
        model, report = identify_model(recordings, description, friction, **options)
    if sticking and "sticking_rad" in report.details:
        _log(f"sticking transition angle: {report.details['sticking_rad']:.3g} rad (0: sgn kept)")
    if count_observer:
        counts = ", ".join(f"{c:.3g}" for c in model.filter_config.count_rad)
        _log(f"count observer on; encoder counts measured: {counts} rad")
    model.save(args.output)
    _log(report.rigid.table())
    _log(
        "training relative RMS per joint: "
        + ", ".join(f"{x:.2%}" for x in report.friction_relative_rms)
    )
    for key, value in report.details.items():
        _log(f"{key}: {value}")
    _log(f"model written to {args.output}")
    return EXIT_OK


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from teleop_force.estimation.batch import evaluate_recordings
    from teleop_force.estimation.estimator import estimator_from_args
    from teleop_force.identification.dynamic_model import DynamicModel

    model = estimator_from_args(DynamicModel.load(args.model), args)
    recordings = _load_recordings(
        args.data, model.n_joints, robot=_reader_robot(model.robot), driver=args.driver
    )
    # evaluate_model's figures, from the streaming estimator's numbers computed in batch
    result = evaluate_recordings(model, recordings)
    payload = {
        "relative_rms": [float(x) for x in result["relative_rms"]],
        "samples": result["samples"],
        "coverage": [float(x) for x in result["coverage"]],
        "friction": model.friction.kind,
        "robot": model.robot,
        "estimator": model.filter_config.estimator,
        "count_observer": model.filter_config.count_observer,
    }
    if args.json:
        print(json.dumps(payload))
    else:
        for j, value in enumerate(payload["relative_rms"]):
            print(
                f"joint {j + 1}: relative RMS {value:.2%}, "
                f"on trained ground {payload['coverage'][j]:.0%}"
            )
        print(f"samples: {payload['samples']}")
    return EXIT_OK


def _cmd_export_json(args: argparse.Namespace) -> int:
    from teleop_force.io.mcap_session import export_session_json

    done = export_session_json(args.recording, args.output)
    if args.json:
        payload = {"source": str(done.source), "target": str(done.target),
                   "messages": done.messages, "skipped": done.skipped}  # fmt: skip
        print(json.dumps(payload))
    else:
        _log(f"{done.messages} messages written to {done.target} (JSON channels)")
    return EXIT_OK


def _cmd_estimate(args: argparse.Namespace) -> int:
    from teleop_force.estimation.batch import BatchEstimator
    from teleop_force.estimation.estimator import estimator_from_args
    from teleop_force.identification.dynamic_model import DynamicModel

    model = estimator_from_args(DynamicModel.load(args.model), args)
    (recording,) = _load_recordings(
        [args.data], model.n_joints, robot=_reader_robot(model.robot), driver=args.driver
    )
    # the streaming estimator's numbers, computed over the whole recording at once
    estimates = BatchEstimator(model).estimate(recording.t_s, recording.q_rad, recording.tau_nm)
    _write_force_table(Path(args.output), recording.t_s, estimates.force_tip_in_base_n)
    _log(f"{recording.t_s.size} estimates written to {args.output}")
    return EXIT_OK


#: Rows formatted at once by :func:`_write_force_table` (bounds the text held in memory).
_FORCE_ROWS_PER_WRITE = 65_536


def _write_force_table(path: Path, t_s: np.ndarray, force_n: np.ndarray) -> None:
    """Write ``t,f_x,f_y,f_z`` rows (``%.17g``: every double reads back exactly) to ``path``.

    One ``%`` format per block of rows instead of one per row: the same text, ~4x faster.
    """
    from teleop_force.errors import DataError

    table = np.column_stack((t_s, force_n))
    try:
        with open(path, "w", encoding="utf-8", newline="\n") as out:
            out.write("t,f_x,f_y,f_z\n")
            for start in range(0, table.shape[0], _FORCE_ROWS_PER_WRITE):
                rows = table[start : start + _FORCE_ROWS_PER_WRITE]
                out.write(
                    ("%.17g,%.17g,%.17g,%.17g\n" * rows.shape[0]) % tuple(rows.ravel().tolist())
                )
    except OSError as exc:
        raise DataError(f"cannot write file: {exc.strerror or exc}", path=path) from None


def _reader_robot(robot: str | None) -> str | None:
    """Return the robot the reader checks the data against (``none`` takes any robot's)."""
    return None if robot == "none" else robot


def _cmd_residual(args: argparse.Namespace) -> int:
    from teleop_force.residual.options import EffectPlacement, ResidualOptions
    from teleop_force.residual.report import write_residual_report

    options = ResidualOptions(
        friction=args.friction,
        offsets=args.offsets,
        effect_placement=EffectPlacement(args.effect_placement),
    )
    if args.model is not None:
        from teleop_force.identification.dynamic_model import DynamicModel
        from teleop_force.residual.from_model import trace_from_model

        if args.friction is not None or args.offsets is not None:
            raise ConfigurationError("--friction and --offsets do not apply with --model")
        model = DynamicModel.load(args.model)
        if args.robot is not None and args.robot != model.robot:
            raise ConfigurationError(
                f"--robot {args.robot} differs from the model's robot {model.robot!r}"
            )
        recordings = _load_recordings(args.data, model.n_joints, _reader_robot(model.robot))
        description = model.description()
        report = trace_from_model(recordings, model, options, str(Path(args.model).resolve()))
    else:
        from teleop_force.residual.loop import trace_residual
        from teleop_force.robots.registry import resolve_robot

        robot = args.robot or "omni"
        recordings = _load_recordings(args.data, robot=_reader_robot(robot))
        description = resolve_robot(robot, recordings[0].q_rad.shape[1])
        if args.effect_test:
            from teleop_force.residual.acceptance import trace_residual_tested

            report = trace_residual_tested(recordings, description, options)
        else:
            report = trace_residual(recordings, description, options)
        for fallback in report.fallbacks:
            _log(f"fallback: {fallback['friction']} refused ({fallback['cause']})")
        if report.failed is not None:
            _log(f"warning: even the simplest baseline failed: {report.failed}")
    if args.output:
        path = write_residual_report(report, Path(args.output), list(description.joint_names))
        _log(f"report written to {path}")
    if args.json:
        print(json.dumps(report.to_json()))
    else:
        for j in range(report.before.size):
            print(
                f"joint {j + 1}: held-out relative RMS "
                f"{report.before[j]:.2%} -> {report.after[j]:.2%}"
            )
        for e in report.effects_json():
            print(
                f"  + {e['description']}: {e['kind']}, "
                f"explains {e['explained']:.1%} of joint {e['joint']}'s residual"
            )
        if not report.effects_json():
            print("no significant effect found")
    return EXIT_OK


def _cmd_report_robots(args: argparse.Namespace) -> int:
    from teleop_force.reports.robots import run_robot_reports

    path = run_robot_reports(
        Path(args.output),
        None if args.datasets is None else Path(args.datasets),
        residual=not args.skip_residual,
        log=_log,
    )
    _log(f"report written to {path}")
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    from teleop_force.cli.demo import DemoConfig, run_demo
    from teleop_force.process.lifetime import StopSignal
    from teleop_force.service.accuracy import AccuracyConfig

    config = DemoConfig(
        duration_s=args.duration,
        headless=args.headless,
        dashboard_port=args.port,
        zenoh_port=args.zenoh_port,
        model=None if args.model is None else Path(args.model),
        record_dir=Path(args.record_dir),
        summary_json=None if args.summary_json is None else Path(args.summary_json),
        motion=args.motion,
        haptic_feedback=args.haptic_feedback,
        accuracy=AccuracyConfig(contact_threshold_n=args.contact_threshold),
        record=not args.no_record,
        service_args=tuple(
            flag
            for flag, on in (("--adapt", args.adapt), ("--zenoh-floor", args.zenoh_floor))
            if on
        )
        + forwarded_estimator_arguments(args),
        slave_args=_plant_effect_args(args),
        **({} if args.rt_priority is None else {"rt_priority": args.rt_priority}),
        **({} if args.nice is None else {"realtime_nice": args.nice}),
    )
    if config.model is not None:
        from teleop_force.identification.dynamic_model import DynamicModel

        DynamicModel.load(config.model)  # a bad model is bad input: exit 2 before starting
    from teleop_force.process.memory import MemoryTrimmer

    with MemoryTrimmer():  # the supervisor runs as long as the demo
        summary = run_demo(config, StopSignal().install())
    return EXIT_OK if summary["ok"] else 1


def _plant_effect_args(args: argparse.Namespace) -> tuple[str, ...]:
    """Return the slave's ``--plant-effect*`` flags of ``demo`` (none without the effect)."""
    if args.plant_effect is None:
        return ()
    from teleop_force.simulation.effects import EFFECT_NAMES

    if args.plant_effect not in EFFECT_NAMES:
        raise ConfigurationError(
            f"--plant-effect {args.plant_effect!r}: not a plant effect; known: "
            + ", ".join(EFFECT_NAMES)
        )
    joint = (
        ()
        if args.plant_effect_joint is None
        else ("--plant-effect-joint", str(args.plant_effect_joint))
    )
    return (
        "--plant-effect", args.plant_effect,
        "--plant-effect-at-s", repr(args.plant_effect_at_s),
        "--plant-effect-scale", repr(args.plant_effect_scale),
        *joint,
    )  # fmt: skip


def _cmd_replay(args: argparse.Namespace) -> int:
    if args.record is not None and not args.with_service:
        raise ConfigurationError("--record needs --with-service (the service records)")
    if args.over_zenoh and args.record is None:
        raise ConfigurationError("--over-zenoh goes with --with-service --record")
    if args.record is not None and not args.over_zenoh:
        return _reestimate(args)
    return _publish(args)


def _replay_model(args: argparse.Namespace, metadata: dict[str, str]) -> tuple[Any, Path]:
    """Load ``--model``, else the recording's model, else the shipped one (``--with-service``).

    The estimator the recording names in its metadata is the one run (as recorded).
    """
    from teleop_force.estimation.estimator import with_recorded_estimator
    from teleop_force.service.force_service import load_model

    recorded = metadata.get("model", "")
    chosen = args.model or (recorded if recorded and Path(recorded).is_file() else None)
    model, path = load_model(None if chosen is None else Path(chosen))
    return with_recorded_estimator(model, metadata), path


def _reestimate(args: argparse.Namespace) -> int:
    """``replay --with-service --record``: the service's recording of a replay, in batch."""
    from teleop_force.io.mcap_session import SessionReader
    from teleop_force.service.reestimation import reestimate_session

    reader = SessionReader(Path(args.recording))
    model, model_path = _replay_model(args, reader.metadata)
    _log(f"re-estimating {reader.path} with {model_path.name} ({model.friction.kind}), in batch")
    done = reestimate_session(
        reader, Path(args.record), model, model_path=model_path, device=args.device
    )
    total = sum(done.replayed.values())
    rate = total / done.duration_s if done.duration_s > 0 else 0.0
    payload: dict[str, Any] = {
        "device": done.device,
        "published": done.replayed,  # what a replay publishes: here, fed to the batch service
        "duration_s": done.duration_s,
        "recorded_span_s": done.recorded_span_s,
        "matched": True,
        "stopped": False,
        "messages_per_s": round(rate, 1),
        "mode": "batch",
        "recorded": {"path": str(done.target), "messages": done.written},
        "service": done.service,
    }
    speedup = done.recorded_span_s / done.duration_s if done.duration_s > 0 else 0.0
    stats = done.service
    _log(
        f"re-estimated {total} messages in {done.duration_s:.2f} s ({speedup:.0f}x the "
        f"recorded span of {done.recorded_span_s:.2f} s): {stats['estimates']['published']} "
        f"estimates, recorded to {done.target}"
    )
    if args.json:
        print(json.dumps(payload))
    return EXIT_OK


def _publish(args: argparse.Namespace) -> int:
    """``replay``: publish over Zenoh at the speed asked (``--with-service``: run the service)."""
    from teleop_force.io.mcap_session import SessionReader
    from teleop_force.io.replay import ReplayConfig, primary_device, replay_session
    from teleop_force.process.lifetime import StopSignal
    from teleop_force.service.force_service import ForceService, ServiceConfig
    from teleop_force.transport.session import open_session, options_from_args

    speed = 0.0 if args.fast else args.speed
    config = ReplayConfig(
        path=Path(args.recording),
        speed=speed,
        device=args.device,
        wait_subscribers_s=0.0 if args.no_wait else args.wait_subscribers,
    )
    reader = SessionReader(config.path)  # unreadable recording: exit 2 before opening zenoh
    device = primary_device(reader, config.device)
    model = model_path = None
    if args.with_service:
        model, model_path = _replay_model(args, reader.metadata)
    stop = StopSignal().install()
    session = open_session(options_from_args(args))
    service = None
    try:
        if model is not None:
            service_config = ServiceConfig(
                device=device,
                master=reader.metadata.get("master_device") or None,
                record_path=None if args.record is None else Path(args.record),
                source="replay",
            )
            service = ForceService(session, model, service_config, model_path=model_path).start()
        _log(
            f"replaying {config.path} (device {device}) at "
            + ("full speed" if speed == 0.0 else f"x{speed:g}")
        )
        result = replay_session(session, config, stop)
        payload: dict[str, Any] = result.to_dict()
        if service is not None:
            expected = result.published.get(f"/{device}/measured_js", 0)
            seqs = service.joint_states.seqs
            done, idle_since = -1, time.perf_counter()
            while seqs.received < expected and time.perf_counter() - idle_since < 10.0:
                if seqs.received != done:  # still progressing: keep waiting
                    done, idle_since = seqs.received, time.perf_counter()
                time.sleep(0.01)
            service.close()
            payload["service"] = service.stats()
    finally:
        if service is not None:
            service.close()
        session.close()
    total = sum(result.published.values())
    _log(
        f"published {total} messages in {result.duration_s:.2f} s "
        f"({result.messages_per_s:.0f} messages/s; recorded span {result.recorded_span_s:.2f} s)"
    )
    if service is not None:
        stats = payload["service"]
        _log(
            f"service: {stats['estimates']['published']} estimates, "
            f"{stats['joint_states']['lost']} joint states lost"
            + (f", recorded to {args.record}" if args.record else "")
        )
    if args.json:
        print(json.dumps(payload))
    return EXIT_OK


def _cmd_teststand_heldout(args: argparse.Namespace) -> int:
    from teleop_force.reports.teststand_heldout import held_out_study

    report = held_out_study(args.folder, args.train_fraction, args.torques, reverse=args.reverse)
    if args.json:
        print(json.dumps(report.to_json()))
    else:
        print("\n".join(report.lines()))
    return EXIT_OK


def _cmd_residual_blind(args: argparse.Namespace) -> int:
    from teleop_force.reports.blind_tests import (
        run_blind_tests,
        run_payload_case,
        write_blind_report,
    )

    cases, payloads = [], []
    for family in args.family.split(","):
        cases += run_blind_tests(args.duration, log=_log, family=family)
        if args.payload:
            payloads.append(run_payload_case(family, args.duration, log=_log))
    path = write_blind_report(cases, Path(args.output), payloads)
    print(path.read_text())
    passed = all(c.passed for c in cases) and all(p.passed for p in payloads)
    return EXIT_OK if passed else 1


def _cmd_generated_report(args: argparse.Namespace) -> int:
    from teleop_force.reports.generated import parse_seeds, run_report
    from teleop_force.simulation.generator_spec import reported_seeds

    if (args.seeds is None) == (args.reported is None):
        raise ConfigurationError("give either --seeds or --reported COMMIT")
    seeds = parse_seeds(args.seeds) if args.seeds else reported_seeds(args.reported)
    _log(f"seeds: {', '.join(str(s) for s in seeds)}")
    results = run_report(seeds, Path(args.output), log=_log)
    if args.json:
        print(json.dumps({"seeds": results}))
    else:
        print((Path(args.output) / "report.md").read_text())
    return EXIT_OK


def _cmd_experiments(args: argparse.Namespace) -> int:
    from teleop_force.reports.experiments import ExperimentOptions, run_experiments

    options = ExperimentOptions(args.duration, args.test_duration, args.seed)
    results = run_experiments(Path(args.output), options, log=_log)
    _log(f"report written to {Path(args.output) / 'report.md'}")
    if args.json:
        print(json.dumps(results, default=float))
    return EXIT_OK


def _cmd_accuracy(args: argparse.Namespace) -> int:
    from teleop_force.reports.accuracy import (
        AccuracyOptions,
        BatchEstimate,
        run_accuracy,
        write_accuracy_report,
    )

    options = AccuracyOptions(
        args.identify_duration,
        args.test_duration,
        args.identify_protocol,
        args.friction,
        args.wn_structure,
        args.trace_residual,
        args.sticking,
        # the identification's choice: with it, the counts and the estimator that goes with it
        args.count_observer,
    )
    overrides: dict[str, object] = dict(given_estimator_flags(args))
    overrides.pop("count_observer", None)
    results = run_accuracy(
        args.family, args.seeds, estimate=BatchEstimate(overrides), options=options, log=_log
    )
    markdown, json_path = write_accuracy_report(results, Path(args.output), options)
    _log(f"report written to {markdown} and {json_path}")
    if args.json:
        print(json.dumps({"sessions": [r.to_json() for r in results]}))
    else:
        print(markdown.read_text())
    return EXIT_OK


def _cmd_bench(args: argparse.Namespace) -> int:
    from teleop_force.bench.main import format_table, options_from_args, run_bench

    result = run_bench(options_from_args(args), log=_log)
    print(json.dumps(result) if args.json else format_table(result))
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser of ``teleop-force``: one subcommand per helper below."""
    parser = argparse.ArgumentParser(prog="teleop-force", description=__doc__.splitlines()[0])
    subparsers = parser.add_subparsers(dest="command", required=True)
    _add_identify(subparsers)
    _add_evaluate(subparsers)
    _add_estimate(subparsers)
    _add_residual(subparsers)
    _add_report_robots(subparsers)
    _add_demo(subparsers)
    _add_serve(subparsers)
    _add_check_driver(subparsers)
    _add_excite(subparsers)
    _add_replay(subparsers)
    _add_export_json(subparsers)
    _add_bench(subparsers)
    _add_experiments(subparsers)
    _add_residual_blind(subparsers)
    _add_accuracy(subparsers)
    _add_teststand_heldout(subparsers)
    _add_generated_report(subparsers)
    return parser


# The subcommands import only light modules (enums, option lists) to build their flags: each
# command imports what it runs when it runs.


def _add_json_flag(parser: argparse.ArgumentParser, help_text: str | None = None) -> None:
    parser.add_argument("--json", action="store_true", help=help_text)


def _add_driver_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--driver", default=None, metavar="NAME|FILE",
        help="the sessions' joint states are this driver's, converted on reading: a built-in "
        "(sensable-phantom) or a driver description file (default: the description a session "
        "recorded by `teleop-force excite` carries; none: the model's coordinates)",
    )  # fmt: skip


def _add_output(
    parser: argparse.ArgumentParser,
    help_text: str | None = None,
    *,
    required: bool = False,
    default: str | None = None,
) -> None:
    parser.add_argument("-o", "--output", required=required, default=default, help=help_text)


def _add_identify(subparsers: _Subparsers) -> None:
    from teleop_force.friction.kinds import FrictionKind
    from teleop_force.robots.kinds import RobotKind

    p = subparsers.add_parser("identify", help="identify rigid-body parameters and friction")
    p.add_argument("data", nargs="+", help="recordings (.csv interchange or .mcap session)")
    p.add_argument(
        "--robot",
        default=RobotKind.OMNI.value,
        help="omni (default), none, dvrk-mtm, teststand, or a description file",
    )
    p.add_argument(
        "--friction",
        choices=[kind.value for kind in FrictionKind],
        default=None,
        help="default: the robot's best baseline (wn; model-cv on dvrk-mtm, cv on teststand)."
        " model-cv: Coulomb + viscous on the model joints' velocities (T qd),"
        " reaching the motors through the coupling (closed chains, cables)",
    )
    p.add_argument(
        "--offsets",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="fit a constant torque per joint (default: the robot's: on for dvrk-mtm and"
        " none, else off)",
    )
    p.add_argument(
        "--sticking",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="look for a sticking (Dahl) state of the Coulomb terms of the CV friction (wn: of"
        " its fallback), its transition angle fitted on the recordings, kept only if it fits"
        " them better than sgn(qd) (it then replaces the standstill dead band); not with"
        " model-cv. Default: the robot's (on for omni, else off)",
    )
    p.add_argument(
        "--wn-fit",
        choices=("adaptive", "batch"),
        default="batch",
        help="train the wavelet network by batch ridge least squares (default, as the"
        " library) or by the paper's Lyapunov adaptation",
    )
    _add_wn_structure(p)
    _add_count_observer(p)
    p.add_argument(
        "--guards",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="check the fit on the last quarter of each recording first (default off: on the"
        " dVRK MTM it made the held-out figures worse): a fit"
        " worse than predicting zero on a joint falls back to the next simpler friction, and"
        " the wavelet network is kept only on joints where it beats the coupled CV there;"
        " every fallback is printed",
    )
    _add_driver_flag(p)
    _add_output(p, "model file to write (JSON)", required=True)
    p.set_defaults(run=_cmd_identify)


def _add_evaluate(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser("evaluate", help="reverse torque computation, relative RMS per joint")
    p.add_argument("model")
    p.add_argument("data", nargs="+")
    add_estimator_arguments(p)
    _add_driver_flag(p)
    _add_json_flag(p)
    p.set_defaults(run=_cmd_evaluate)


def _add_estimate(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser("estimate", help="contact-force estimate for every sample")
    p.add_argument("model")
    p.add_argument("data")
    add_estimator_arguments(p)
    _add_driver_flag(p)
    _add_output(p, required=True)
    p.set_defaults(run=_cmd_estimate)


def _add_export_json(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser(
        "export-json", help="rewrite a recorded session with JSON channels (the old layout)"
    )
    p.add_argument("recording", help="session .mcap (CDR or JSON, complete or truncated)")
    _add_output(p, "JSON session .mcap to write", required=True)
    _add_json_flag(p)
    p.set_defaults(run=_cmd_export_json)


def _add_residual(subparsers: _Subparsers) -> None:
    # The light options module only (the enums): the loop itself is imported when it runs.
    from teleop_force.residual.options import COMMAND_LINE_FRICTION_KINDS, EffectPlacement

    p = subparsers.add_parser(
        "residual", help="find, trace and add what the model lacks; report before/after"
    )
    p.add_argument("data", nargs="+")
    p.add_argument(
        "--model",
        default=None,
        metavar="MODEL",
        help="keep this model's identified parameters and trace what DATA shows it lacks"
        " (default: fit the model from DATA)",
    )
    p.add_argument("--robot", default=None, help="default: omni, or the model's robot")
    p.add_argument(
        "--friction",
        choices=[kind.value for kind in COMMAND_LINE_FRICTION_KINDS],
        default=None,
        help="friction of the model the residual is taken from (default: the robot's best"
        " baseline: wn; model-cv on dvrk-mtm; model-cv: in model coordinates)",
    )
    p.add_argument(
        "--offsets",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="fit a constant torque per joint with the friction (default: the robot's: on"
        " for dvrk-mtm and without a body, else off)",
    )
    p.add_argument(
        "--effect-placement",
        choices=[placement.value for placement in EffectPlacement],
        default=EffectPlacement.AUTO.value,
        help="where a found effect acts: on its motor joint, at the model joint (through the"
        " coupling), either (model joint if confirmed); auto: either with model-cv friction",
    )
    p.add_argument(
        "--effect-test",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="search the first 2/3 of each recording and keep an effect only if it passes a"
        " held-out sign-flip test on the last third, family-wise level 0.01 (not with"
        " --model; default off)",
    )
    _add_json_flag(p)
    _add_output(p, "folder for the report (markdown, plots, model.json)")
    p.set_defaults(run=_cmd_residual)


def _add_report_robots(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser("report-robots", help="tables and plots of the real-robot datasets")
    _add_output(p, "folder for the report", default="reports/robots")
    p.add_argument("--datasets", help="datasets folder (default: <repo>/../shared/datasets)")
    p.add_argument("--skip-residual", action="store_true", help="skip the slow MTM residual loop")
    p.set_defaults(run=_cmd_report_robots)


def _add_demo(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser(
        "demo", help="master, slave, service and dashboard over Zenoh on loopback"
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="run S seconds once everything is up (default: until Ctrl-C)",
    )
    p.add_argument("--headless", action="store_true", help="do not start the dashboard")
    p.add_argument(
        "--port", type=int, default=8080, metavar="P", help="dashboard HTTP port (default 8080)"
    )
    p.add_argument(
        "--zenoh-port",
        type=int,
        default=None,
        metavar="P",
        help="port of the Zenoh router on 127.0.0.1 (default 7447, rmw_zenoh's: started, or "
        "joined when one listens there)",
    )
    p.add_argument("--model", default=None, help="model JSON (default: the shipped omni_sim.json)")
    p.add_argument("--record-dir", default="recordings", help="where the session is recorded")
    p.add_argument(
        "--summary-json", default=None, metavar="PATH", help="write the final summary as JSON"
    )
    p.add_argument(
        "--motion",
        choices=("palpation", "random"),
        default="palpation",
        help="what the simulated operator does with the master",
    )
    p.add_argument(
        "--haptic-feedback", action="store_true", help="feed the estimated force back to the master"
    )
    p.add_argument(
        "--contact-threshold",
        type=float,
        default=0.1,
        metavar="N",
        help="true force above which a sample counts as contact (default 0.1 N)",
    )
    p.add_argument("--no-record", action="store_true", help="do not record the session")
    p.add_argument("--adapt", action="store_true", help="start the service with WN adaptation on")
    add_estimator_arguments(p)
    p.add_argument(
        "--zenoh-floor", action="store_true",
        help="run the service as its Zenoh floor (same traffic, no work; for benchmarks)",
    )  # fmt: skip
    p.add_argument(
        "--rt-priority", type=int, default=None, metavar="P",
        help="SCHED_FIFO priority of the service (master and slave loops at P+1; 0: ordinary "
        "scheduling; needs root or CAP_SYS_NICE, else ignored; default 10)",
    )  # fmt: skip
    p.add_argument(
        "--nice", type=int, default=None, metavar="N",
        help="nice value of the children and the supervisor (default -10, where permitted)",
    )  # fmt: skip
    from master_slave.process_args import add_plant_effect_arguments

    add_plant_effect_arguments(p)
    p.set_defaults(run=_cmd_demo)


def _serve(argv: Sequence[str]) -> int:
    """``teleop-force serve ...``: the service process's own command line, in this process."""
    from teleop_force.service import force_service

    return force_service.main(argv, prog="teleop-force serve")


def _add_serve(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser(
        "serve",
        help="the force-estimation service alone, against a live device (teleop-force serve "
        "--help: its flags)",
        add_help=False,
    )
    # Never parsed here: main() hands everything after "serve" to the service's own parser.
    p.set_defaults(run=lambda args: _serve([]))


def _cmd_check_driver(args: argparse.Namespace) -> int:
    from teleop_force.cli.check_driver import run

    return run(args)


def _add_check_driver(subparsers: _Subparsers) -> None:
    from teleop_force.cli.check_driver import add_arguments

    p = subparsers.add_parser(
        "check-driver",
        help="check a driver description against the live driver (measured_js vs measured_cp; "
        "--probe-force-n: efforts vs measured_cf)",
    )
    add_arguments(p)
    p.set_defaults(run=_cmd_check_driver)


def _cmd_excite(args: argparse.Namespace) -> int:
    from teleop_force.cli.excite import run

    return run(args)


def _add_excite(subparsers: _Subparsers) -> None:
    from teleop_force.cli.excite import add_arguments

    p = subparsers.add_parser(
        "excite",
        help="play the training trajectory through a live driver (servo_cp) and record it, "
        "for identify",
    )
    add_arguments(p)
    p.set_defaults(run=_cmd_excite)


def _add_replay(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser("replay", help="publish a recorded session over Zenoh as if live")
    p.add_argument("recording", help="session .mcap")
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="X",
        help="time scale: 2 = twice as fast, 0 = as fast as possible (default 1)",
    )
    p.add_argument("--fast", action="store_true", help="as fast as possible (same as --speed 0)")
    p.add_argument("--device", default=None, help="primary device (default: from the recording)")
    p.add_argument(
        "--with-service",
        action="store_true",
        help="run the force-estimation service in this process on the replayed stream",
    )
    p.add_argument(
        "--model",
        default=None,
        help="model for --with-service (default: the recording's, else the shipped one)",
    )
    p.add_argument(
        "--record",
        default=None,
        metavar="PATH",
        help="with --with-service: write the recording the service would make of the replay,"
        " its estimates computed again, in batch (nothing is published)",
    )
    p.add_argument(
        "--over-zenoh",
        action="store_true",
        help="with --with-service --record: publish over Zenoh at the speed asked and record"
        " the in-process service live, instead of re-estimating in batch",
    )
    p.add_argument(
        "--wait-subscribers",
        type=float,
        default=10.0,
        metavar="S",
        help="wait up to S s for a subscriber of the joint states before starting",
    )
    p.add_argument("--no-wait", action="store_true", help="start at once")
    _add_json_flag(p, "print what was published as JSON")
    add_zenoh_arguments(p)
    p.set_defaults(run=_cmd_replay)


def _add_bench(subparsers: _Subparsers) -> None:
    from teleop_force.bench.main import add_bench_arguments

    p = subparsers.add_parser(
        "bench", help="performance figures of this machine, measured in one run"
    )
    add_bench_arguments(p)
    p.set_defaults(run=_cmd_bench)


def _add_experiments(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser(
        "experiments", help="reproduce the paper's experiments on the simulated Omni"
    )
    _add_output(p, "folder for report.md, report.json and figures", required=True)
    p.add_argument(
        "--duration", type=float, default=240.0, help="training session length [s] (paper: 240)"
    )
    p.add_argument("--test-duration", type=float, default=60.0, help="test session length [s]")
    p.add_argument("--seed", type=int, default=1)
    _add_json_flag(p)
    p.set_defaults(run=_cmd_experiments)


def _add_wn_structure(p: argparse.ArgumentParser) -> None:
    from teleop_force.friction.kinds import WN_STRUCTURES

    p.add_argument(
        "--wn-structure",
        choices=WN_STRUCTURES,
        default=WN_STRUCTURES[0],
        help="on-cv (default): the wavelet network is trained on what the coupled CV leaves and"
        " adds to it; alone: the paper's network, the whole friction, blended with the coupled"
        " CV off its trained ground",
    )


def _add_accuracy(subparsers: _Subparsers) -> None:
    from teleop_force.friction.kinds import FrictionKind

    p = subparsers.add_parser(
        "accuracy", help="held-out force accuracy per simulated plant family and seed"
    )
    p.add_argument(
        "--family", nargs="+", choices=("one", "two"), default=["one"], help="plant families"
    )
    p.add_argument("--seeds", nargs="+", type=int, default=[1], help="one session per seed")
    p.add_argument(
        "--identify-duration", type=float, default=120.0, help="free motion to identify on [s]"
    )
    p.add_argument(
        "--test-duration", type=float, default=60.0, help="teleoperation touching a floor [s]"
    )
    p.add_argument(
        "--identify-protocol",
        choices=("teleoperation", "slow-stretch"),
        default="teleoperation",
        help="free motion to identify on: band-limited random motion (default), or the same"
        " with slow stretches (40 %% of the time at 1/50-1/5 of the speed)",
    )
    p.add_argument(
        "--friction",
        choices=[kind.value for kind in FrictionKind],
        default=None,
        help="friction to identify (default: the Omni's, as `teleop-force identify` fits it)",
    )
    _add_wn_structure(p)
    p.add_argument(
        "--trace-residual",
        action="store_true",
        help="before testing, add what the residual loop finds the identified model lacks on"
        " its own free motion (as `teleop-force residual --model`)",
    )
    p.add_argument(
        "--sticking",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="identify with or without looking for a sticking state of the Coulomb terms"
        " (`identify --sticking`; default: as `identify` does for the Omni, on)",
    )
    add_estimator_arguments(p)
    _add_output(p, "folder for accuracy.md and accuracy.json", required=True)
    _add_json_flag(p, "print the figures as one JSON object")
    p.set_defaults(run=_cmd_accuracy)


def _add_count_observer(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--count-observer",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="identify a model that estimates on the encoder count observer's angles (the"
        " counts measured on the recordings, the observer at 400 Hz; default: the robot's, on"
        " for the Omni)",
    )


def _add_residual_blind(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser(
        "residual-blind", help="blind tests of the residual loop on simulated effects"
    )
    _add_output(p, "folder for blind.md and blind.json", required=True)
    p.add_argument("--duration", type=float, default=60.0, help="session length [s]")
    p.add_argument(
        "--family",
        default="one,two",
        help="simulated plant families, comma-separated (default one,two)",
    )
    p.add_argument(
        "--payload",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also trace a session with a tip mass against a model of a clean one (--model)",
    )
    p.set_defaults(run=_cmd_residual_blind)


def _add_teststand_heldout(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser(
        "teststand-heldout",
        help="test stand held out in time: identify on the first part, score on the rest",
    )
    p.add_argument("folder", help="folder of test-stand .dat logs with the ATI force")
    p.add_argument(
        "--train-fraction", type=float, default=2.0 / 3.0, metavar="F",
        help="fraction of the samples, from the start, to identify on (default 2/3)",
    )  # fmt: skip
    p.add_argument(
        "--torques", choices=("target", "measured"), default=None,
        help="torque source (default: target when its file is there, else measured)",
    )  # fmt: skip
    p.add_argument(
        "--reverse", action="store_true",
        help="identify on the last fraction instead and score on the first samples",
    )  # fmt: skip
    _add_json_flag(p)
    p.set_defaults(run=_cmd_teststand_heldout)


def _add_generated_report(subparsers: _Subparsers) -> None:
    p = subparsers.add_parser(
        "generated-report",
        help="the defaults on plants drawn by the generator (docs/plant_generator.md)",
    )
    p.add_argument("--seeds", default=None, help="plant seeds, e.g. 1-20 (the choice seeds)")
    p.add_argument(
        "--reported", default=None, metavar="COMMIT",
        help="the 20 reported seeds of the commit that froze the last choice (full id)",
    )  # fmt: skip
    _add_output(p, "folder for seeds.jsonl and report.md (a rerun resumes)", required=True)
    _add_json_flag(p)
    p.set_defaults(run=_cmd_generated_report)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    words = list(sys.argv[1:] if argv is None else argv)
    if words[:1] == ["serve"]:
        return _serve(words[1:])
    parser = build_parser()
    args = parser.parse_args(words)
    try:
        return int(args.run(args))
    except TeleopForceError as exc:
        _log(f"teleop-force {args.command}: {exc}")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
