"""The project's module structure: files and lines per package, the largest files, and the import graph's cycles.

    .venv/bin/python scripts/architecture.py          # table per package under estimators/ + cycles anywhere

Every ``import`` and ``from ... import`` of a project module counts, at any depth (also inside functions), so a
deferred import cannot hide a cycle. ``tests/test_architecture.py`` holds the rules this prints.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

REPO_DIR = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES = ("ingest", "calib", "estimators", "sim", "app")


def module_files(root: Path = REPO_DIR) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the project packages (packages as ``pkg.__init__``'s
    name ``pkg``)."""
    files = {}
    for package in PROJECT_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            files[name] = path
    return files


def import_graph(files: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports (``from pkg import name`` counts as ``pkg.name`` when that is a
    module, else as ``pkg``)."""
    graph: dict[str, set[str]] = defaultdict(set)
    for name, path in files.items():
        graph[name]
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in files else node.module
                           for alias in node.names]
            for target in targets:
                while target and target not in files:
                    target = target.rpartition(".")[0]
                if target and target != name and target.split(".")[0] in PROJECT_PACKAGES:
                    graph[name].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = [0]

    def visit(node: str) -> None:
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for successor in graph.get(node, ()):
            if successor not in index:
                visit(successor)
                low[node] = min(low[node], low[successor])
            elif successor in on_stack:
                low[node] = min(low[node], index[successor])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph) + 100))
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def line_count(path: Path) -> int:
    return len(path.read_text().splitlines())


def package_table(files: dict[str, Path], top: str = "estimators") -> list[tuple[str, int, int, str, int]]:
    """(package, files, lines, largest file, its lines) for ``top`` and each of its subpackages."""
    by_package: dict[str, list[Path]] = defaultdict(list)
    for name, path in files.items():
        if name.split(".")[0] != top:
            continue
        by_package[str(path.parent.relative_to(REPO_DIR))].append(path)
    rows = []
    for package, paths in sorted(by_package.items()):
        largest = max(paths, key=line_count)
        rows.append((package, len(paths), sum(map(line_count, paths)), largest.name, line_count(largest)))
    return rows


def main() -> int:
    files = module_files()
    print(f"{'package':28s} {'files':>5s} {'lines':>6s}  largest file")
    for package, n_files, lines, largest, largest_lines in package_table(files):
        print(f"{package:28s} {n_files:5d} {lines:6d}  {largest} ({largest_lines})")
    found = cycles(import_graph(files))
    print(f"import cycles among {len(files)} project modules: {len(found)}")
    for component in found:
        print("  " + " <-> ".join(component))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
