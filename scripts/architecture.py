"""The project's module structure: files and lines per package, the largest files, the import graph's cycles and
the functions over 100 lines.

    .venv/bin/python scripts/architecture.py    # estimators/ table per package; cycles and long functions anywhere

Every ``import`` and ``from ... import`` of a project module counts, at any depth (also inside functions), so a
deferred import cannot hide a cycle; and importing ``pkg.sub.mod`` counts as importing ``pkg`` and ``pkg.sub`` too,
since Python runs their ``__init__`` files first, so a package ``__init__`` that imports its own submodules is a
cycle. ``tests/test_architecture.py`` holds the rules this prints.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

REPO_DIR = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES = ("ingest", "calib", "estimators", "sim", "workflows", "app")
#: Functions longer than this [lines] are listed (the issue's closing note shows them).
MAX_FUNCTION_LINES = 100


def module_files(root: Path = REPO_DIR) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the project packages under ``root`` (packages as
    ``pkg.__init__``'s name ``pkg``); a package that does not exist there has no modules."""
    files = {}
    for package in PROJECT_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            files[name] = path
    return files


def import_graph(files: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports (``from pkg import name`` counts as ``pkg.name`` when that is a
    module, else as ``pkg``), each with the packages above it: importing ``pkg.sub.mod`` runs ``pkg/__init__.py``
    and ``pkg/sub/__init__.py`` first. A module's edge to itself is left out."""
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
                if target.split(".")[0] not in PROJECT_PACKAGES:
                    continue
                while target:  # the module itself (or the deepest existing one), then each package above it
                    if target in files and target != name:
                        graph[name].add(target)
                    target = target.rpartition(".")[0]
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


def long_functions(files: dict[str, Path], max_lines: int = MAX_FUNCTION_LINES) -> dict[str, list[tuple[str, int]]]:
    """Top-level package -> (``module:function`` or ``module:Class.method``, lines) of every function longer than
    ``max_lines`` (from its ``def`` to its last line; nested functions count within the one around them and on
    their own), longest first."""
    found: dict[str, list[tuple[str, int]]] = defaultdict(list)
    for name, path in files.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        scopes = [(tree, "")]
        while scopes:
            scope, prefix = scopes.pop()
            for node in ast.iter_child_nodes(scope):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    scopes.append((node, f"{prefix}{node.name}."))
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    n_lines = node.end_lineno - node.lineno + 1
                    if n_lines > max_lines:
                        found[name.split(".")[0]].append((f"{name}:{prefix}{node.name}", n_lines))
    return {package: sorted(rows, key=lambda row: (-row[1], row[0])) for package, rows in sorted(found.items())}


def main() -> int:
    files = module_files()
    print(f"{'package':28s} {'files':>5s} {'lines':>6s}  largest file")
    for package, n_files, lines, largest, largest_lines in package_table(files):
        print(f"{package:28s} {n_files:5d} {lines:6d}  {largest} ({largest_lines})")
    found = cycles(import_graph(files))
    print(f"import cycles among {len(files)} project modules (package __init__ files and deferred imports "
          f"included): {len(found)}")
    for component in found:
        print("  " + " <-> ".join(component))
    long = long_functions(files)
    print(f"functions over {MAX_FUNCTION_LINES} lines: {sum(map(len, long.values()))}")
    for package, rows in long.items():
        print(f"  {package}")
        for function, n_lines in rows:
            print(f"    {function} ({n_lines})")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
