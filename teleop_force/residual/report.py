"""Write a residual-loop report: JSON (CONTRACT.md), markdown and PNG plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from teleop_force.identification.effects import describe_reach
from teleop_force.residual.loop import ResidualReport


def write_residual_report(
    report: ResidualReport, folder: Path, joint_names: list[str] | None = None
) -> Path:
    """Write ``report.json``, ``report.md``, ``model.json`` and plots into ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "report.json").write_text(json.dumps(report.to_json(), indent=1))
    report.model.save(folder / "model.json")
    n = report.before.size
    names = joint_names or [f"joint {j + 1}" for j in range(n)]

    fig, ax = plt.subplots(figsize=(6, 3.5))
    xs = np.arange(n)
    ax.bar(xs - 0.2, 100 * report.before, 0.4, label="before")
    ax.bar(xs + 0.2, 100 * report.after, 0.4, label="after")
    ax.set_xticks(xs, names)
    ax.set_ylabel("held-out relative RMS [%]")
    ax.legend()
    ax.set_title("Error per joint, held-out blocks")
    fig.tight_layout()
    fig.savefig(folder / "error_per_joint.png", dpi=110)
    plt.close(fig)

    lines = [
        "# Residual loop report",
        "",
        f"Samples scored (held-out blocked cross-validation): {report.samples}",
        "",
        "| joint | before | after |",
        "|---|---|---|",
    ]
    for j in range(n):
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
    for k, item in enumerate(report.plots.get("effects", [])):
        spec = item["spec"]
        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.plot(item["x"], item["before"], ".", ms=2, alpha=0.5, label="residual before")
        ax.plot(item["x"], item["after"], ".", ms=2, alpha=0.5, label="residual after")
        ax.set_xlabel(spec.variable if spec.shape != "constant" else "t")
        ax.set_ylabel(f"joint {spec.joint + 1} filtered residual [N m]")
        ax.set_title(spec.describe())
        ax.legend(markerscale=4)
        fig.tight_layout()
        name = f"effect_{k + 1}.png"
        fig.savefig(folder / name, dpi=110)
        plt.close(fig)
        lines += ["", f"![{spec.describe()}]({name})"]
    lines += ["", "![error per joint](error_per_joint.png)", ""]
    path = folder / "report.md"
    path.write_text("\n".join(lines))
    return path
