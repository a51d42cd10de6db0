"""Print and save how many inputs each fuzz target got, at the end of the session."""

from __future__ import annotations

import json
from pathlib import Path

from .targets import COUNTS, cleanup

OUT = Path(__file__).resolve().parents[2] / "test-output" / "fuzz_counts.json"


def counts_table() -> list[str]:
    """One line per target: total inputs and their outcomes."""
    lines = []
    for name, outcomes in sorted(COUNTS.items()):
        detail = ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))
        lines.append(f"{name:42s} {sum(outcomes.values()):7d}  ({detail})")
    return lines


def pytest_terminal_summary(terminalreporter) -> None:
    if not COUNTS:
        return
    terminalreporter.section("fuzz inputs per target")
    for line in counts_table():
        terminalreporter.write_line(line)
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(json.dumps({k: dict(v) for k, v in sorted(COUNTS.items())}, indent=1) + "\n")
    terminalreporter.write_line(f"(saved to {OUT})")


def pytest_sessionfinish(session, exitstatus) -> None:
    cleanup()
