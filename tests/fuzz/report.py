"""Run every fuzz target N times and print how many inputs each got (for the closing note).

    uv run python -m tests.fuzz.report                 # 2000 examples per target
    uv run python -m tests.fuzz.report --examples 500 --json test-output/fuzz_report.json

Each hypothesis target of :mod:`tests.fuzz.test_fuzz_inputs` runs with ``max_examples=N``;
the service and slave counters are checked on N fuzzed payloads each
(:mod:`tests.fuzz.test_fuzz_receivers`). Exit status 1 if a target found a new failure.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import json
import os
import sys
import time
import traceback
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.fuzz.report")
    parser.add_argument("--examples", type=int, default=2000, help="examples per target")
    parser.add_argument("--json", type=Path, default=None, help="also write the counts here")
    parser.add_argument("-k", default="", help="only tests whose name contains this")
    args = parser.parse_args(argv)
    os.environ["TELEOP_FUZZ_EXAMPLES"] = str(args.examples)
    targets = importlib.import_module("tests.fuzz.targets")
    modules = [
        importlib.import_module("tests.fuzz.test_fuzz_inputs"),
        importlib.import_module("tests.fuzz.test_fuzz_receivers"),
    ]
    failures: dict[str, str] = {}
    timings: dict[str, float] = {}
    for module in modules:
        for name, test in inspect.getmembers(module, inspect.isfunction):
            if not name.startswith("test_") or args.k not in name:
                continue
            needs_fixtures = inspect.signature(test).parameters
            if needs_fixtures and not getattr(test, "hypothesis", None):
                continue
            started = time.perf_counter()
            print(f"running {name} ...", file=sys.stderr, flush=True)
            try:
                test()
            except Exception as exc:  # report every target, then fail
                failures[name] = "".join(traceback.format_exception_only(exc)).strip()
                print(traceback.format_exc(), file=sys.stderr)
            timings[name] = round(time.perf_counter() - started, 1)
    print(f"\nfuzz inputs per target ({args.examples} examples per hypothesis target)")
    total = 0
    for name, outcomes in sorted(targets.COUNTS.items()):
        n = sum(outcomes.values())
        total += n
        detail = ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))
        print(f"  {name:42s} {n:8d}  ({detail})")
    print(f"  {'total':42s} {total:8d}")
    for name, error in failures.items():
        print(f"FAILED {name}: {error.splitlines()[-1][:300]}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        payload = {
            "examples_per_target": args.examples,
            "counts": {k: dict(v) for k, v in sorted(targets.COUNTS.items())},
            "known_issues": {
                k: f"{v.kind.__name__} /{v.pattern}/ in {', '.join(v.modules)}"
                for k, v in targets.KNOWN_ISSUES.items()
            },
            "seconds": timings,
            "failures": failures,
        }
        args.json.write_text(json.dumps(payload, indent=1) + "\n")
    targets.cleanup()
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
