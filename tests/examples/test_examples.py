"""The examples and the README's Python snippets run and print what they promise.

Each example runs as a user would run it (``python examples/NN_*.py``), in a subprocess. The
Zenoh clients (``02``, ``04`` and the README's) are tested in ``test_estimate_clients.py``.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
README = ROOT / "README.md"


def run_python(args: list[str], timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(
        [sys.executable, *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )
    assert result.returncode == 0, f"exit {result.returncode}\n{result.stdout}\n{result.stderr}"
    return result


def readme_python_block(marker: str) -> str:
    """The README's ```python block that contains ``marker``."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)
    matching = [b for b in blocks if marker in b]
    assert len(matching) == 1, f"expected one README python block with {marker!r}"
    return matching[0]


def test_every_example_is_tested() -> None:
    names = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
    assert names == [
        "01_identify_and_estimate.py",
        "02_subscribe_to_estimates.py",
        "03_close_the_loop.py",
        "04_subscribe_with_rclpy.py",
    ]


def test_identify_and_estimate() -> None:
    out = run_python([str(EXAMPLES / "01_identify_and_estimate.py")]).stdout
    errors = {a: float(e) for a, e in re.findall(r"f_([xyz]): RMS error ([0-9.]+) N", out)}
    true = {a: float(t) for a, t in re.findall(r"f_([xyz]):.*true force RMS ([0-9.]+) N", out)}
    assert set(errors) == {"x", "y", "z"}, out
    # Pressing down: f_y carries the force (~1.7 N); the estimate is within 15 % of it.
    assert true["y"] > 1.0, out
    assert errors["y"] < 0.15 * true["y"], out


def test_close_the_loop_names_the_planted_cogging() -> None:
    out = run_python([str(EXAMPLES / "03_close_the_loop.py")]).stdout
    found = re.findall(r"found: joint (\d+): (\S+)\(([^)]*)\)", out)
    assert found, out
    assert found[0][0] == "1" and found[0][2] == "q1", out  # first: joint 1, periodic in q1
    before, after = map(float, re.search(r"joint 1: .* ([0-9.]+)% -> ([0-9.]+)%", out).groups())
    assert after < 0.6 * before, out


def test_readme_identify_snippet_runs() -> None:
    run_python(["-c", readme_python_block("identify_model")])
