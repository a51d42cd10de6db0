"""Force accuracy on data the model has not seen, per plant family and seed.

``teleop-force accuracy`` runs it (docs/cli.md).

For one family and seed (:func:`session_accuracy`):

1. **identify** a model on 120 s of *free* motion (default: the teleoperation protocol,
   band-limited random motion, no contact; ``identify_protocol="slow-stretch"``: the same
   motion with slow stretches, :func:`~teleop_force.simulation.session.slow_stretch_protocol`)
   with the Omni's default friction and offsets, as ``teleop-force identify`` fits them
   (:func:`~teleop_force.robots.registry.robot_defaults`; ``friction=`` names another kind);
   and, with ``trace_residual``, add what the residual loop finds that model lacks on
   that same free motion (:func:`~teleop_force.residual.from_model.trace_from_model`);
2. **simulate** 60 s of teleoperation touching a soft floor on the *same arm*
   (:func:`~teleop_force.simulation.floor_touch.floor_touch_protocol`, another session seed:
   other motion, other noise): never used to fit;
3. **estimate** the tip force with a pluggable ``estimate(model, session) -> (N, 3)``
   (default :class:`BatchEstimate`: the library's batch estimator, optionally with
   :class:`~teleop_force.identification.filtered_regressor.FilterConfig` overrides such as
   ``estimator="observer"``), and filter the true force with ``reference_filter(force, dt)``
   (default: what the estimator's filters do to a force, :class:`CascadeReference`).

Figures, after the filters' warm-up (``warmup_s``), over samples with a finite estimate:

- contact error: RMS ``|F_hat - F|`` over contact samples (``|F| > 0``), also as % of RMS
  ``|F|`` in contact;
- false force in free motion: RMS ``|F_hat|`` over samples without contact [N];
- error in contact at rest: RMS ``|F_hat - F|`` in contact with every true joint speed
  below 0.01 rad/s [N] (and how many such samples);
- lag vs bias in contact: lag = RMS ``|F_ref - F|`` (what filtering the true force like the
  estimate costs), bias = RMS ``|F_hat - F_ref|`` (what the model gets wrong);
- the protocol's own figures: contact fraction and RMS contact force.

Plant family one's arm is the same for every seed; family two's arm is drawn per seed
(:class:`~teleop_force.simulation.plant_two.PlantTwoConfig`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from time import perf_counter
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.friction.kinds import WN_STRUCTURES, FrictionKind, wn_on_fallback
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel, sticking_rad_of
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.pipeline import identify_model
from teleop_force.identification.prepared import wavelet_options_for
from teleop_force.io.interchange_csv import Recording
from teleop_force.lowpass import lowpass_batch
from teleop_force.robots.kinds import RobotKind
from teleop_force.robots.omni import omni_description
from teleop_force.robots.registry import robot_defaults
from teleop_force.simulation.families import PlantFamily
from teleop_force.simulation.floor_touch import floor_touch_protocol
from teleop_force.simulation.plant import PlantConfig
from teleop_force.simulation.plant_two import PlantTwoConfig
from teleop_force.simulation.session import (
    SimulatedSession,
    slow_stretch_protocol,
    teleoperation_protocol,
)

#: ``estimate(model, session) -> (N, 3)`` force of the tip on the environment [N].
Estimate = Callable[[DynamicModel, SimulatedSession], np.ndarray]
#: ``reference_filter(force_true (N, 3), dt) -> (N, 3)``.
ReferenceFilter = Callable[[np.ndarray, float], np.ndarray]

#: Every true joint speed below this is "at rest" [rad/s].
REST_SPEED_RAD_S = 0.01
#: Offset between the identification and the test session's seeds.
TEST_SEED_OFFSET = 100
#: The free-motion protocols a model can be identified on, by name.
IDENTIFY_PROTOCOLS: dict[str, Callable[..., SimulatedSession]] = {
    "teleoperation": teleoperation_protocol,
    "slow-stretch": slow_stretch_protocol,
}
#: The protocol identified on by default.
DEFAULT_IDENTIFY_PROTOCOL = "teleoperation"


@dataclass(frozen=True)
class BatchEstimate:
    """The library's batch estimator as an ``estimate`` callable, with filter overrides.

    ``filter_overrides`` replace fields of the model's
    :class:`~teleop_force.identification.filtered_regressor.FilterConfig` before estimating
    (e.g. ``{"estimator": "observer", "observer_hz": 12.0}``): a plain, sweepable parameter.
    """

    filter_overrides: Mapping[str, Any] = field(default_factory=dict)

    def config(self, model: DynamicModel) -> FilterConfig:
        """Return the filter configuration the estimate runs with."""
        try:
            return dataclasses.replace(model.filter_config, **dict(self.filter_overrides))
        except TypeError as error:
            raise ConfigurationError(f"bad filter override: {error}") from error

    def __call__(self, model: DynamicModel, session: SimulatedSession) -> np.ndarray:
        """Estimate the tip force on every sample of ``session`` (N, 3)."""
        from teleop_force.estimation.batch import BatchEstimator

        if self.filter_overrides:
            model = dataclasses.replace(model, filter_config=self.config(model))
        estimates = BatchEstimator(model).estimate(session.t_s, session.q_rad, session.tau_nm)
        return np.asarray(estimates.force_tip_in_base_n)

    def describe(self) -> str:
        """One line naming the estimator and its overrides."""
        if not self.filter_overrides:
            return "batch (model's filters)"
        return "batch (" + ", ".join(f"{k}={v}" for k, v in self.filter_overrides.items()) + ")"


@dataclass(frozen=True)
class CascadeReference:
    """What the estimator's filters do to a force: its pre-filter, then ``L``, then the lag.

    The pre-filter (:attr:`~teleop_force.identification.filtered_regressor.FilterConfig.
    estimator_prefilter`: ``L_v``, or the observer's own stages) and ``L`` at ``cutoff_hz`` (at
    ``observer_hz`` for the momentum observer, whose response to an external torque is first
    order) are first-order low-passes (:func:`~teleop_force.lowpass.lowpass_batch`), then the
    observer's output Butterworth if it has one (the estimator's own
    :func:`~teleop_force.estimation.batch.output_filter_loop`); the output is
    ``torque_lag_samples`` late.
    """

    config: FilterConfig = field(default_factory=FilterConfig)

    def __call__(self, force_n: np.ndarray, dt_s: float) -> np.ndarray:
        """Filter the true force (N, 3) sampled every ``dt_s``."""
        force = np.asarray(force_n, dtype=float)
        t = np.arange(force.shape[0]) * float(dt_s)
        config = self.config
        second_hz = config.observer_hz if config.observer else config.cutoff_hz
        prefilter_hz, stages = config.estimator_prefilter
        out = force
        for _ in range(stages):
            out = lowpass_batch(out, t, prefilter_hz)
        out = lowpass_batch(out, t, second_hz)
        output_hz = config.estimator_output_hz
        if output_hz > 0.0:
            from teleop_force.estimation.batch import output_filter_loop

            out = np.array(out, dtype=float)
            starts = np.zeros(out.shape[0], dtype=bool)
            starts[:1] = True
            dt = np.full(out.shape[0], float(dt_s))
            output_filter_loop(out, dt, starts, 2.0 * math.pi * output_hz)
        lag = int(config.torque_lag_samples)
        if lag > 0:
            out = np.concatenate([np.repeat(out[:1], lag, axis=0), out[:-lag]])
        return np.asarray(out)


@dataclass(frozen=True)
class AccuracyOptions:
    """The protocol's choices (defaults: issue #19's 120 s free, 60 s touching).

    Attributes:
        identify_duration_s: Free motion to identify on [s].
        test_duration_s: Teleoperation touching the floor [s].
        identify_protocol: One of :data:`IDENTIFY_PROTOCOLS` (the free motion's kind).
        friction: Friction kind to identify (``None``: the Omni's default, as
            ``teleop-force identify`` fits it).
        wn_structure: The wavelet network's structure (one of
            :data:`~teleop_force.friction.kinds.WN_STRUCTURES`), as ``identify`` fits it.
        trace_residual: Close the loop on the identification's free motion before testing:
            the residual loop from the identified model
            (:func:`~teleop_force.residual.from_model.trace_from_model`, as ``teleop-force
            residual --model``) adds what that motion shows the model lacks.
        sticking: Look for a sticking state of the Coulomb terms in the free motion
            (``identify --sticking``; ``None``: as ``identify`` does for the Omni, on, but
            not with ``model-cv`` friction; ``True`` with ``model-cv``: ConfigurationError).
        count_observer: Identify a model that estimates on the encoder count observer's
            angles (``identify --count-observer``; ``None``: as ``identify`` does for the
            Omni, on).

    """

    identify_duration_s: float = 120.0
    test_duration_s: float = 60.0
    identify_protocol: str = DEFAULT_IDENTIFY_PROTOCOL
    friction: str | None = None
    wn_structure: str = WN_STRUCTURES[0]
    trace_residual: bool = False
    sticking: bool | None = None
    count_observer: bool | None = None

    def __post_init__(self) -> None:
        for name in ("identify_duration_s", "test_duration_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 1.0):
                raise ConfigurationError(f"{name} must be > 1 s, got {value}")
        _identify_protocol(self.identify_protocol)
        if self.friction is not None:
            FrictionKind.parse(self.friction)
        wn_on_fallback(self.wn_structure)
        if self.sticking is True and self.friction == "model-cv":
            raise ConfigurationError("sticking goes with friction cv, coupled-cv or wn")


@dataclass(frozen=True)
class SessionAccuracy:
    """The figures of one family and seed (module docstring); forces in N, errors in %."""

    family: str
    seed: int
    estimator: str
    friction: str
    wn_structure: str | None
    identify_protocol: str
    contact_fraction: float
    rms_contact_force_n: float
    contact_error_n: float
    contact_error_pct: float
    free_false_force_n: float
    rest_contact_error_n: float
    rest_contact_samples: int
    lag_n: float
    bias_n: float
    nan_samples: int
    identify_wall_s: float
    simulate_wall_s: float
    #: What the residual loop added on the free motion (``trace_residual``), one line each.
    found_effects: tuple[str, ...] = ()
    #: The sticking transition angle the identification kept [rad] (0: none).
    sticking_rad: float = 0.0
    #: The encoder counts the count observer clipped to [rad] (empty: no count observer).
    count_rad: tuple[float, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """Return the figures as a JSON-ready dict (NaN as ``None``)."""
        return {
            key: (None if isinstance(value, float) and not math.isfinite(value) else value)
            for key, value in dataclasses.asdict(self).items()
        }


def describe_estimator(config: FilterConfig) -> str:
    """Describe the estimator a filter configuration runs (bandwidths, band, observer)."""
    if config.observer:
        prefilter_hz, stages = config.estimator_prefilter
        words = [f"momentum observer {config.observer_hz:g} Hz on {stages} x {prefilter_hz:g} Hz"]
        if config.observer_output_hz > 0.0:
            words.append(f"Butterworth {config.observer_output_hz:g} Hz")
    else:
        words = [f"filter L {config.cutoff_hz:g} Hz on L_v {config.velocity_cutoff_hz:g} Hz"]
    if config.standstill_band_rad_s > 0.0:
        words.append(f"dead band {config.standstill_band_rad_s:g} rad/s")
    if config.count_observer:
        words.append("on the count observer's angles")
    return ", ".join(words)


def _rms_norm(x: np.ndarray) -> float:
    if x.shape[0] == 0:
        return math.nan
    return float(np.sqrt(np.mean(np.sum(x * x, axis=1))))


def accuracy_figures(
    session: SimulatedSession,
    force_hat_n: np.ndarray,
    force_ref_n: np.ndarray,
    warmup_s: float,
) -> dict[str, float | int]:
    """Compute the module docstring's figures from the true, estimated and reference forces."""
    force = session.f_tip_in_base_n
    estimate = np.asarray(force_hat_n, dtype=float)
    reference = np.asarray(force_ref_n, dtype=float)
    if estimate.shape != force.shape or reference.shape != force.shape:
        raise ConfigurationError(
            f"estimate {estimate.shape} and reference {reference.shape} must be {force.shape}"
        )
    finite = np.all(np.isfinite(estimate), axis=1)
    keep = (session.t_s >= session.t_s[0] + warmup_s) & finite
    contact = np.linalg.norm(force, axis=1) > 0.0
    rest = np.all(np.abs(session.qd_true_rad_s) < REST_SPEED_RAD_S, axis=1)
    in_contact = keep & contact
    rms_force = _rms_norm(force[in_contact])
    error = _rms_norm(estimate[in_contact] - force[in_contact])
    at_rest = in_contact & rest
    return {
        "contact_fraction": float(np.mean(contact[keep])) if keep.any() else math.nan,
        "rms_contact_force_n": rms_force,
        "contact_error_n": error,
        "contact_error_pct": 100.0 * error / rms_force if rms_force > 0 else math.nan,
        "free_false_force_n": _rms_norm(estimate[keep & ~contact]),
        "rest_contact_error_n": _rms_norm(estimate[at_rest] - force[at_rest]),
        "rest_contact_samples": int(np.count_nonzero(at_rest)),
        "lag_n": _rms_norm(reference[in_contact] - force[in_contact]),
        "bias_n": _rms_norm(estimate[in_contact] - reference[in_contact]),
        "nan_samples": int(np.count_nonzero(~finite)),
    }


def _recording(session: SimulatedSession) -> Recording:
    return Recording(session.t_s, session.q_rad, session.tau_nm)


def identify_free_motion(
    family: PlantFamily | str,
    seed: int,
    duration_s: float = 120.0,
    *,
    protocol: str = DEFAULT_IDENTIFY_PROTOCOL,
    friction: str | None = None,
    wn_structure: str = WN_STRUCTURES[0],
    sticking: bool | None = None,
    count_observer: bool | None = None,
) -> tuple[DynamicModel, SimulatedSession]:
    """Identify the Omni's default model on ``duration_s`` of free motion of the family's arm.

    ``protocol``: one of :data:`IDENTIFY_PROTOCOLS`; ``friction``: a friction kind instead of
    the Omni's default; ``wn_structure``: the network's (``--wn-structure``); ``sticking``,
    ``count_observer``: as ``identify --sticking``, ``--count-observer`` (``None``:
    ``identify``'s default for the Omni).
    """
    family = PlantFamily.parse(family)
    run = _identify_protocol(protocol)
    session = run(duration_s, seed, family=family, plant_config=plant_config(family, seed))
    defaults = robot_defaults(RobotKind.OMNI)  # what `teleop-force identify` fits by default
    kind = FrictionKind.parse(friction if friction is not None else defaults.friction)
    if sticking is None:
        sticking = defaults.sticking_with(kind)
    model, _ = identify_model(
        [_recording(session)],
        omni_description(),
        kind,
        wavelet=wavelet_options_for(wn_structure),
        offsets=defaults.offsets,
        sticking=sticking,
        count_observer=defaults.count_observer if count_observer is None else count_observer,
    )
    return model, session


def _identify_protocol(name: str) -> Callable[..., SimulatedSession]:
    """Return the protocol of :data:`IDENTIFY_PROTOCOLS` called ``name``; raise if unknown."""
    try:
        return IDENTIFY_PROTOCOLS[name]
    except KeyError:
        choices = ", ".join(IDENTIFY_PROTOCOLS)
        raise ConfigurationError(
            f"identify_protocol must be one of {choices}, got {name!r}"
        ) from None


def plant_config(family: PlantFamily, seed: int) -> PlantConfig | PlantTwoConfig | None:
    """Return the plant configuration of ``family`` for ``seed`` (family two: drawn per seed)."""
    return PlantTwoConfig(instance_seed=seed) if family is PlantFamily.TWO else None


def session_accuracy(
    family: PlantFamily | str,
    seed: int,
    *,
    estimate: Estimate | None = None,
    reference_filter: ReferenceFilter | None = None,
    options: AccuracyOptions | None = None,
    model: DynamicModel | None = None,
    log: Callable[[str], None] = lambda _: None,
) -> SessionAccuracy:
    """Identify on free motion, test on floor touching, return the figures (module docstring).

    ``estimate`` defaults to :class:`BatchEstimate` (no overrides); ``reference_filter`` to
    the :class:`CascadeReference` of the estimate's filters (``estimate.config(model)`` when
    the estimate has one, else the model's). ``model``: skip the identification (a model of
    the same arm, identified elsewhere; ConfigurationError with ``options.trace_residual``,
    which runs on the identification's motion).
    """
    family = PlantFamily.parse(family)
    options = options or AccuracyOptions()
    if model is not None and options.trace_residual:
        raise ConfigurationError(
            "trace_residual runs on the identification's free motion: not with a given model"
        )
    estimator = estimate if estimate is not None else BatchEstimate()
    started = perf_counter()
    found: tuple[str, ...] = ()
    if model is None:
        model, free = identify_free_motion(
            family,
            seed,
            options.identify_duration_s,
            protocol=options.identify_protocol,
            friction=options.friction,
            wn_structure=options.wn_structure,
            sticking=options.sticking,
            count_observer=options.count_observer,
        )
        if options.trace_residual:
            model, found = _trace_residual(model, free)
    identify_wall = perf_counter() - started
    log(f"family {family} seed {seed}: identified ({model.friction.kind}) in {identify_wall:.1f} s")
    for line in found:
        log(f"family {family} seed {seed}: the residual loop added {line}")
    started = perf_counter()
    test = floor_touch_protocol(
        options.test_duration_s,
        seed + TEST_SEED_OFFSET,
        family=family,
        plant_config=plant_config(family, seed),
    )
    simulate_wall = perf_counter() - started
    force_hat = np.asarray(estimator(model, test), dtype=float)
    if reference_filter is None:
        config_of = getattr(estimator, "config", None)
        config = config_of(model) if callable(config_of) else model.filter_config
        reference_filter = CascadeReference(config)
    reference = reference_filter(test.f_tip_in_base_n, test.sample_interval_s)
    figures = accuracy_figures(test, force_hat, reference, model.filter_config.warmup_s)
    describe = getattr(estimator, "describe", None)
    name = describe() if callable(describe) else getattr(estimator, "__name__", "custom")
    if callable(config_of := getattr(estimator, "config", None)):
        name = f"{name}: {describe_estimator(config_of(model))}"
    result = SessionAccuracy(
        family=family.value,
        seed=int(seed),
        estimator=name,
        friction=str(model.friction.kind),
        wn_structure=(
            model.friction.structure if isinstance(model.friction, WaveletNetwork) else None
        ),
        identify_protocol=options.identify_protocol,
        identify_wall_s=round(identify_wall, 1),
        simulate_wall_s=round(simulate_wall, 1),
        found_effects=found,
        sticking_rad=sticking_rad_of(model.friction),
        count_rad=model.filter_config.count_rad if model.filter_config.count_observer else (),
        **figures,  # type: ignore[arg-type]
    )
    log(
        f"family {family} seed {seed}: contact {100 * result.contact_fraction:.1f} % of the time,"
        f" RMS contact force {result.rms_contact_force_n:.3f} N,"
        f" contact error {result.contact_error_pct:.2f} %"
    )
    return result


def _trace_residual(
    model: DynamicModel, free: SimulatedSession
) -> tuple[DynamicModel, tuple[str, ...]]:
    """Return the model with what the residual loop finds on its free motion, and those lines."""
    from teleop_force.residual.from_model import trace_from_model

    report = trace_from_model([_recording(free)], model)
    lines = tuple(
        f"{traced.spec.describe()} ({100 * traced.explained:.0f} % of the residual, held out)"
        for traced in report.effects
    )
    if report.payload is not None:
        lines += ("a payload (the last link's inertial parameters)",)
    return report.model, lines


def run_accuracy(
    families: Iterable[PlantFamily | str],
    seeds: Sequence[int],
    *,
    estimate: Estimate | None = None,
    reference_filter: ReferenceFilter | None = None,
    options: AccuracyOptions | None = None,
    log: Callable[[str], None] = lambda _: None,
) -> list[SessionAccuracy]:
    """:func:`session_accuracy` for every family and seed (families outer)."""
    return [
        session_accuracy(
            family,
            int(seed),
            estimate=estimate,
            reference_filter=reference_filter,
            options=options,
            log=log,
        )
        for family in families
        for seed in seeds
    ]


_COLUMNS = (
    ("family", "family", "{}"),
    ("seed", "seed", "{}"),
    ("contact_fraction", "contact [%]", "{:.1f}"),
    ("rms_contact_force_n", "RMS F in contact [N]", "{:.3f}"),
    ("contact_error_n", "error in contact [N]", "{:.3f}"),
    ("contact_error_pct", "error in contact [%]", "{:.2f}"),
    ("free_false_force_n", "false force, free [N]", "{:.3f}"),
    ("rest_contact_error_n", "error at rest in contact [N]", "{:.3f}"),
    ("rest_contact_samples", "rest samples", "{}"),
    ("lag_n", "lag [N]", "{:.3f}"),
    ("bias_n", "bias [N]", "{:.3f}"),
)


def accuracy_table(results: Sequence[SessionAccuracy]) -> str:
    """Return a markdown table of the figures, one row per session."""
    header = "| " + " | ".join(title for _, title, _ in _COLUMNS) + " |"
    rule = "|" + "---|" * len(_COLUMNS)
    rows = []
    for result in results:
        cells = []
        for key, _, fmt in _COLUMNS:
            value = getattr(result, key)
            if key == "contact_fraction":
                value = 100.0 * value
            if isinstance(value, float) and not math.isfinite(value):
                cells.append("-")
            else:
                cells.append(fmt.format(value))
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join([header, rule, *rows])


def write_accuracy_report(
    results: Sequence[SessionAccuracy], folder: Path, options: AccuracyOptions | None = None
) -> tuple[Path, Path]:
    """Write ``accuracy.md`` and ``accuracy.json`` into ``folder``; return both paths."""
    options = options or AccuracyOptions()
    folder.mkdir(parents=True, exist_ok=True)
    estimators = sorted({r.estimator for r in results})
    frictions = sorted({" ".join(filter(None, (r.friction, r.wn_structure))) for r in results})
    protocols = sorted({r.identify_protocol for r in results})
    lines = [
        "# Force accuracy on held-out sessions",
        "",
        f"Per family and seed: a model identified on {options.identify_duration_s:g} s of free"
        f" motion ({', '.join(protocols)} protocol; friction {', '.join(frictions)}), tested on"
        f" {options.test_duration_s:g} s of teleoperation touching a soft floor (another"
        " session of the same arm, not used to fit). Estimator: " + ", ".join(estimators) + ".",
        "",
        accuracy_table(results),
        "",
    ]
    if options.sticking is not False:
        lines += [
            "The identification looked for a sticking state of the Coulomb terms"
            " (`--sticking`); the transition angle it kept per seed (0: none, sgn(qd) and the"
            " dead band):",
            "",
            *(f"- {r.family} seed {r.seed}: {r.sticking_rad:.3g} rad" for r in results),
            "",
        ]
    if any(r.count_rad for r in results):
        lines += [
            "The estimates ran on the encoder count observer's angles (`--count-observer`);"
            " the counts each identification measured [rad]:",
            "",
            *(
                f"- {r.family} seed {r.seed}: " + " / ".join(f"{c:.3g}" for c in r.count_rad)
                for r in results
                if r.count_rad
            ),
            "",
        ]
    if options.trace_residual:
        lines += [
            "The residual loop ran on each identification's free motion before the test"
            " (`--trace-residual`) and added:",
            "",
            *(
                f"- {r.family} seed {r.seed}: " + ("; ".join(r.found_effects) or "nothing")
                for r in results
            ),
            "",
        ]
    markdown = folder / "accuracy.md"
    markdown.write_text("\n".join(lines))
    payload = {
        "identify_duration_s": options.identify_duration_s,
        "test_duration_s": options.test_duration_s,
        "identify_protocol": options.identify_protocol,
        "friction": options.friction,
        "wn_structure": options.wn_structure,
        "trace_residual": options.trace_residual,
        "sticking": options.sticking,
        "count_observer": options.count_observer,
        "sessions": [r.to_json() for r in results],
    }
    path = folder / "accuracy.json"
    path.write_text(json.dumps(payload, indent=2))
    return markdown, path
