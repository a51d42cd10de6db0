"""The residual loop's report: its result (:class:`ResidualReport`) and the files written.

JSON (docs/cli.md), markdown and PNG plots.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, describe_reach


@dataclass(frozen=True)
class TracedEffect:
    """An effect the loop added, with its held-out figures."""

    spec: BasisSpec
    explained: float
    joint_rms_before: float
    joint_rms_after: float
    #: Motor torque per unit of the effect's torque when it acts at a model joint (None: on
    #: the joint alone).
    reach: tuple[float, ...] | None = None

    def to_json(self) -> dict[str, Any]:
        """Return the form of docs/cli.md (``reach`` only for an effect at a model joint)."""
        kind = self.spec.kind
        if self.spec.variable == f"qd{self.spec.joint + 1}" and self.spec.shape != "stribeck":
            kind = "velocity-dependent friction"  # the joint's own velocity: not a coupling
        out: dict[str, Any] = {
            "joint": self.spec.joint + 1,
            "depends_on": self.spec.depends_on(),
            "kind": kind,
            "explained": round(float(self.explained), 6),
            "description": self.spec.describe(),
            "joint_rms_before": float(self.joint_rms_before),
            "joint_rms_after": float(self.joint_rms_after),
        }
        if self.reach is not None:
            out["reach"] = [float(w) for w in self.reach]
        return out


@dataclass(frozen=True)
class TracedPayload:
    """A payload the loop added: a change of the last link's inertial parameters."""

    #: The last link (1-based) and the joint (0-based) it helps most.
    link: int
    joint: int
    #: Joints (0-based) its torque reaches, the angles it depends on.
    reached: tuple[int, ...]
    depends_on: tuple[str, ...]
    explained: float
    joint_rms_before: float
    joint_rms_after: float
    #: The identified change of the base parameters (filled by the final fit).
    base_change: tuple[float, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """Return the form of docs/cli.md: an effect that reaches several joints."""
        return {
            "joint": self.joint + 1,
            "joints": [j + 1 for j in self.reached],
            "depends_on": list(self.depends_on),
            "kind": "payload",
            "explained": round(float(self.explained), 6),
            "description": f"link {self.link}: inertial parameters (mass, first moments,"
            " inertia) changed",
            "joint_rms_before": float(self.joint_rms_before),
            "joint_rms_after": float(self.joint_rms_after),
            "base_parameter_change": [float(x) for x in self.base_change],
        }


@dataclass(frozen=True, eq=False)
class EffectPlot:
    """A joint's filtered residual [N m] against an effect's variable, before and after it."""

    spec: BasisSpec
    #: The effect's variable at the scored samples (time for an offset).
    x: np.ndarray
    before: np.ndarray
    after: np.ndarray


@dataclass(frozen=True, eq=False)
class ResidualReport:
    """Result of :func:`~teleop_force.residual.loop.trace_residual`."""

    #: Held-out relative RMS per joint before and after the effects.
    before: np.ndarray
    after: np.ndarray
    effects: tuple[TracedEffect, ...]
    #: The model refitted with the effects on all data.
    model: DynamicModel
    #: Samples scored.
    samples: int
    #: Per accepted effect: ``effect``, ``kind``, ``gain``, ``control_gain``.
    history: tuple[dict[str, Any], ...] = ()
    #: One plot per accepted effect.
    effect_plots: tuple[EffectPlot, ...] = ()
    #: Candidates that passed the search but not a control or the whole-model check.
    rejected: tuple[dict[str, Any], ...] = ()
    #: A payload found (a model in hand only, :mod:`teleop_force.residual.from_model`).
    payload: TracedPayload | None = None
    #: The model file the residual was taken against (None: the model was fitted here).
    baseline_model: str | None = None
    #: The baseline's friction (after any fallback; None: a model in hand).
    friction: str | None = None
    #: Every baseline refused as a failed fit: ``friction``, ``cause``.
    fallbacks: tuple[dict[str, str], ...] = ()
    #: Why even the simplest baseline failed (None: it did not).
    failed: str | None = None
    #: The held-out test of each effect the search accepted
    #: (:mod:`~teleop_force.residual.acceptance`; empty: not tested).
    tested: tuple[dict[str, Any], ...] = ()
    #: Relative RMS per joint on the test part, before and after the tested effects.
    test_before: np.ndarray | None = None
    test_after: np.ndarray | None = None

    def effects_json(self) -> list[dict[str, Any]]:
        """Return the JSON ``effects``: the payload first, then the other effects in order."""
        payload = [] if self.payload is None else [self.payload.to_json()]
        return payload + [e.to_json() for e in self.effects]

    def to_json(self) -> dict[str, Any]:
        """Return the JSON object of ``teleop-force residual --json``."""
        out: dict[str, Any] = {
            "before": [float(x) for x in self.before],
            "after": [float(x) for x in self.after],
            "effects": self.effects_json(),
            "samples": self.samples,
            "held_out": "blocked cross-validation over contiguous time blocks",
        }
        if self.friction is not None:
            out["friction"] = self.friction
            out["fallbacks"] = [dict(f) for f in self.fallbacks]
            out["failed"] = self.failed
        if self.tested:
            out["tested"] = [dict(t) for t in self.tested]
        if self.test_before is not None and self.test_after is not None:
            out["test_before"] = [float(x) for x in self.test_before]
            out["test_after"] = [float(x) for x in self.test_after]
        if self.baseline_model is not None:
            out["baseline_model"] = self.baseline_model
            out["held_out"] = (
                "before: the model as given (not fitted on DATA); after: the found effects"
                " by blocked cross-validation over contiguous time blocks"
            )
        return out


def write_residual_report(
    report: ResidualReport, folder: Path, joint_names: list[str] | None = None
) -> Path:
    """Write ``report.json``, ``report.md``, ``model.json`` and plots into ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "report.json").write_text(json.dumps(report.to_json(), indent=1))
    report.model.save(folder / "model.json")
    names = joint_names or [f"joint {j + 1}" for j in range(report.before.size)]
    _plot_error_per_joint(report, names, folder / "error_per_joint.png")
    lines = _markdown_tables(report, names)
    for k, item in enumerate(report.effect_plots):
        name = f"effect_{k + 1}.png"
        _plot_effect(item, folder / name)
        lines += ["", f"![{item.spec.describe()}]({name})"]
    lines += ["", "![error per joint](error_per_joint.png)", ""]
    path = folder / "report.md"
    path.write_text("\n".join(lines))
    return path


def _plot_error_per_joint(report: ResidualReport, names: list[str], path: Path) -> None:
    """Bar chart of the held-out relative RMS per joint, before and after."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    xs = np.arange(report.before.size)
    ax.bar(xs - 0.2, 100 * report.before, 0.4, label="before")
    ax.bar(xs + 0.2, 100 * report.after, 0.4, label="after")
    ax.set_xticks(xs, names)
    ax.set_ylabel("held-out relative RMS [%]")
    ax.legend()
    ax.set_title("Error per joint, held-out blocks")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _markdown_tables(report: ResidualReport, names: list[str]) -> list[str]:
    """Lines of the markdown report: errors per joint, then the effects found."""
    lines = [
        "# Residual loop report",
        "",
        f"Samples scored (held-out blocked cross-validation): {report.samples}",
        "",
        "| joint | before | after |",
        "|---|---|---|",
    ]
    for j in range(report.before.size):
        lines.append(f"| {names[j]} | {report.before[j]:.2%} | {report.after[j]:.2%} |")
    if report.baseline_model is not None:
        lines[1:1] = ["", f"Residual against the model `{report.baseline_model}`."]
    lines += ["", "## Effects found", ""]
    found = report.effects_json()
    if not found:
        lines.append("None: nothing lowered the held-out error significantly.")
    else:
        lines += [
            "| # | joint | acts on (motor torque per unit) | depends on | kind | explained"
            " | joint RMS before | after |",
            "|---|---|---|---|---|---|---|---|",
        ]
    for k, e in enumerate(found):
        if "joints" in e:
            acts = ", ".join(f"joint {j}" for j in e["joints"])
        else:
            acts = describe_reach(e["joint"], e.get("reach"))
        lines.append(
            f"| {k + 1} | {e['joint']} | {acts} | {', '.join(e['depends_on'])} | {e['kind']}"
            f" | {e['explained']:.1%} | {e['joint_rms_before']:.2%} | {e['joint_rms_after']:.2%} |"
        )
    return lines


def _plot_effect(item: EffectPlot, path: Path) -> None:
    """Plot the joint's filtered residual against the effect's variable, before and after."""
    import matplotlib.pyplot as plt

    spec = item.spec
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(item.x, item.before, ".", ms=2, alpha=0.5, label="residual before")
    ax.plot(item.x, item.after, ".", ms=2, alpha=0.5, label="residual after")
    ax.set_xlabel(spec.variable if spec.shape != "constant" else "t")
    ax.set_ylabel(f"joint {spec.joint + 1} filtered residual [N m]")
    ax.set_title(spec.describe())
    ax.legend(markerscale=4)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
