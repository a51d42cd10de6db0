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
        out: dict[str, Any] = {
            "joint": self.spec.joint + 1,
            "depends_on": self.spec.depends_on(),
            "kind": self.spec.kind,
            "explained": round(float(self.explained), 6),
            "description": self.spec.describe(),
            "joint_rms_before": float(self.joint_rms_before),
            "joint_rms_after": float(self.joint_rms_after),
        }
        if self.reach is not None:
            out["reach"] = [float(w) for w in self.reach]
        return out


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

    def to_json(self) -> dict[str, Any]:
        """Return the JSON object of ``teleop-force residual --json``."""
        return {
            "before": [float(x) for x in self.before],
            "after": [float(x) for x in self.after],
            "effects": [e.to_json() for e in self.effects],
            "samples": self.samples,
            "held_out": "blocked cross-validation over contiguous time blocks",
        }


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
    lines += ["", "## Effects found", ""]
    if not report.effects:
        lines.append("None: nothing lowered the held-out error significantly.")
    else:
        lines += [
            "| # | joint | acts on (motor torque per unit) | depends on | kind | explained"
            " | joint RMS before | after |",
            "|---|---|---|---|---|---|---|---|",
        ]
    for k, effect in enumerate(report.effects):
        e = effect.to_json()
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
