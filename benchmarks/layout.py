"""Print the shape of a checkout's package: module sizes, import cycles, subpackage cycles.

Modules per folder, the largest module and function, import cycles between modules, and cycles
between subpackages (a subpackage importing one that imports it back).

    uv run python benchmarks/layout.py                 # this checkout's teleop_force/
    uv run python benchmarks/layout.py --root OTHER    # another checkout (e.g. a git worktree)
    uv run python benchmarks/layout.py --json

Only the standard library is used (``ast``), so it measures any revision without importing it.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

PACKAGE = "teleop_force"


@dataclass(frozen=True)
class LayoutFigures:
    """What :func:`measure` reads off a package tree."""

    modules: int
    lines: int
    modules_per_folder: dict[str, int]
    largest_module: tuple[str, int]
    largest_function: tuple[str, int]
    functions_over_100_lines: int
    import_cycles: list[list[str]]
    package_cycles: list[list[str]]


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(tree: ast.Module, name: str, is_package: bool, known: set[str]) -> set[str]:
    """Project modules imported anywhere in the module (deferred imports included)."""
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".")
                anchor = anchor if is_package else anchor[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [base] + [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for target in targets:
            if target in known and target != name:
                found.add(target)
    return found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0

    def visit(v: str) -> None:
        nonlocal counter
        index[v] = low[v] = counter
        counter += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(10_000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def measure(root: Path) -> LayoutFigures:
    """Measure the ``teleop_force`` package under ``root``."""
    files = sorted((root / PACKAGE).rglob("*.py"))
    sources = {_module_name(f, root): (f, f.read_text()) for f in files}
    known = set(sources)
    graph: dict[str, set[str]] = {}
    per_folder: Counter[str] = Counter()
    largest_module = ("", 0)
    largest_function = ("", 0)
    over_100 = 0
    total = 0
    for name, (path, text) in sources.items():
        lines = text.count("\n")
        total += lines
        folder = str(path.parent.relative_to(root))
        if path.name != "__init__.py":
            per_folder[folder] += 1
        if lines > largest_module[1]:
            largest_module = (str(path.relative_to(root)), lines)
        tree = ast.parse(text)
        graph[name] = _imports(tree, name, path.name == "__init__.py", known)
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = (node.end_lineno or node.lineno) - node.lineno + 1
                over_100 += length > 100
                if length > largest_function[1]:
                    where = f"{path.relative_to(root)}:{node.name}"
                    largest_function = (where, length)
    # the front door (lazy imports of everything) and package __init__ re-exports are not
    # dependencies of the code; leave them out of the cycle search
    code_graph = {
        k: {w for w in v if w in sources and sources[w][0].name != "__init__.py"}
        for k, v in graph.items()
        if sources[k][0].name != "__init__.py"
    }
    packages: dict[str, set[str]] = {}
    for module, targets in code_graph.items():
        here = ".".join(module.split(".")[:2]) if module.count(".") >= 2 else module
        for target in targets:
            there = ".".join(target.split(".")[:2]) if target.count(".") >= 2 else target
            if there != here:
                packages.setdefault(here, set()).add(there)
    return LayoutFigures(
        modules=len(files),
        lines=total,
        modules_per_folder=dict(sorted(per_folder.items())),
        largest_module=largest_module,
        largest_function=largest_function,
        functions_over_100_lines=over_100,
        import_cycles=_cycles(code_graph),
        package_cycles=_cycles(packages),
    )


def main(argv: list[str] | None = None) -> int:
    """Print the figures of one checkout."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    figures = measure(args.root)
    if args.json:
        print(json.dumps(asdict(figures), indent=2))
        return 0
    print(f"modules: {figures.modules} ({figures.lines} lines)")
    for folder, count in figures.modules_per_folder.items():
        print(f"  {folder}: {count}")
    print(f"largest module: {figures.largest_module[0]} ({figures.largest_module[1]} lines)")
    print(f"largest function: {figures.largest_function[0]} ({figures.largest_function[1]} lines)")
    print(f"functions over 100 lines: {figures.functions_over_100_lines}")
    print(f"module import cycles: {len(figures.import_cycles)}")
    for cycle in figures.import_cycles:
        print("  " + " <-> ".join(cycle))
    print(f"subpackage cycles: {len(figures.package_cycles)}")
    for cycle in figures.package_cycles:
        print("  " + " <-> ".join(cycle))
    return 0


if __name__ == "__main__":
    sys.exit(main())
