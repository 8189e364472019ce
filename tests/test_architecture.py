"""The layer rule: ingest -> calib -> estimators -> workflows -> app (sim beside workflows); no computation layer
imports the UI toolkits."""

from __future__ import annotations

import ast
import re
import subprocess
import sys

import pytest

from ingest import log_formats
from scripts import architecture
from tests.conftest import REPO_DIR

#: What each top-level package may import from the project.
ALLOWED = {
    "ingest": {"ingest"},
    "calib": {"ingest", "calib"},
    "estimators": {"ingest", "calib", "estimators"},
    "workflows": {"ingest", "calib", "estimators", "workflows"},
    "sim": {"ingest", "calib", "estimators", "sim"},
    "app": {"ingest", "calib", "estimators", "workflows", "sim", "app"},
}
PROJECT_PACKAGES = set(ALLOWED)
UI_MODULES = {"streamlit", "plotly", "tsdownsample"}
#: The front-ends' own toolkits, which the workflow layer never imports.
FRONT_END_MODULES = {"argparse", "dask", "distributed"}


def _imported_top_modules(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.lineno, node.module.split(".")[0]


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_layers_import_only_downwards(package):
    violations = []
    for path in sorted((REPO_DIR / package).rglob("*.py")):
        for lineno, module in _imported_top_modules(path):
            if module in PROJECT_PACKAGES and module not in ALLOWED[package]:
                violations.append(f"{path.relative_to(REPO_DIR)}:{lineno} imports {module}")
            if package != "app" and module in UI_MODULES:
                violations.append(f"{path.relative_to(REPO_DIR)}:{lineno} imports UI module {module}")
            if package == "workflows" and module in FRONT_END_MODULES:
                violations.append(f"{path.relative_to(REPO_DIR)}:{lineno} imports front-end module {module}")
    assert not violations, "\n".join(violations)


#: The steps a workflow assembles (docs/workflows.md): a front-end calls the workflow, never these.
WORKFLOW_STEPS = {"run_estimators", "config_from_calibration", "tune_calibration", "with_filter_figures",
                  "tau_replay", "choose_tau", "calibrate", "px4_parameters", "ardupilot_parameters",
                  "write_calibration", "calibration_to_dict"}


def test_no_front_end_assembles_workflow_steps():
    violations = []
    for path in sorted((REPO_DIR / "app").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and not node.module.startswith("workflows"):
                violations += [f"{path.relative_to(REPO_DIR)}:{node.lineno} imports {alias.name} from {node.module}"
                               for alias in node.names if alias.name in WORKFLOW_STEPS]
    assert not violations, "\n".join(violations)


#: Estimator subpackages that hold one filter each: none imports another.
FILTER_PACKAGES = ("estimators.three_stage", "estimators.direct", "estimators.indirect")
#: What the shared layers of ``estimators`` may import inside ``estimators`` (besides themselves).
SHARED_LAYER_IMPORTS = {
    "estimators.inputs.records": {"estimators.config"},
    "estimators.core": {"estimators.config", "estimators.environment", "estimators.inputs.records"},
    "estimators.sun": {"estimators.config", "estimators.environment", "estimators.core.linalg"},
}
MAX_MODULE_LINES = 600


def test_no_import_cycles_anywhere():
    """Every import counts, deferred ones inside functions too, and an import of ``pkg.mod`` is one of ``pkg``
    (its ``__init__`` runs first); scripts/architecture.py prints the same."""
    found = architecture.cycles(architecture.import_graph(architecture.module_files()))
    assert not found, "\n".join(" <-> ".join(component) for component in found)


def _write_tree(root, modules):
    for name, text in modules.items():
        path = root.joinpath(*name.split(".")).with_suffix(".py")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_a_package_init_that_imports_a_module_importing_the_package_is_a_cycle(tmp_path):
    """``ingest/__init__`` -> ``ingest.reader`` (deferred) -> ``ingest.sub.errors``, which runs ``ingest/__init__``
    and ``ingest/sub/__init__`` first; an ``__init__`` importing a module that imports nothing is no cycle."""
    _write_tree(tmp_path, {
        "ingest.__init__": "from ingest.leaf import VALUE\n",
        "ingest.leaf": "VALUE = 1\n",
        "ingest.reader": "def read():\n    from ingest.sub.errors import Error\n    return Error\n",
        "ingest.sub.__init__": "",
        "ingest.sub.errors": "class Error(Exception):\n    pass\n",
        "calib.__init__": "",
        "calib.use": "from ingest.sub import errors\n",
    })
    graph = architecture.import_graph(architecture.module_files(tmp_path))
    assert graph["calib.use"] == {"ingest", "ingest.sub", "ingest.sub.errors"}
    assert graph["ingest.reader"] == {"ingest", "ingest.sub", "ingest.sub.errors"}
    assert graph["ingest"] == {"ingest.leaf"}
    assert architecture.cycles(graph) == []
    _write_tree(tmp_path, {"ingest.__init__": "from ingest.reader import read\n"})
    assert architecture.cycles(architecture.import_graph(architecture.module_files(tmp_path))) == [
        ["ingest", "ingest.reader"]]


def test_long_functions_are_listed_per_package(tmp_path):
    body = "    x = 0\n" * (architecture.MAX_FUNCTION_LINES - 2)
    _write_tree(tmp_path, {
        "ingest.__init__": "",
        "ingest.long": (f"def at_the_limit():\n{body}    return x\n\n\n"
                        f"class Reader:\n    def over(self):\n    {body.replace(chr(10), chr(10) + '    ')}"
                        f"    y = 1\n        return y\n"),
    })
    assert architecture.long_functions(architecture.module_files(tmp_path)) == {
        "ingest": [("ingest.long:Reader.over", architecture.MAX_FUNCTION_LINES + 1)]}


def test_no_ingest_function_over_100_lines():
    assert "ingest" not in architecture.long_functions(architecture.module_files())


def test_filters_do_not_import_each_other_and_shared_layers_stay_below_them():
    graph = architecture.import_graph(architecture.module_files())
    violations = []
    for module, with_packages in graph.items():
        # a package above an imported module is in the graph because its __init__ runs: not an import of its own
        imported = {target for target in with_packages
                    if not any(other.startswith(target + ".") for other in with_packages)}
        own = next((p for p in FILTER_PACKAGES if module == p or module.startswith(p + ".")), None)
        for target in imported:
            other = next((p for p in FILTER_PACKAGES if target == p or target.startswith(p + ".")), None)
            if own and other and other != own:
                violations.append(f"{module} imports {target}")
        layer = next((p for p in SHARED_LAYER_IMPORTS if module == p or module.startswith(p + ".")), None)
        if layer is not None:
            for target in imported:
                if target.startswith("estimators") and not target.startswith(layer) and not any(
                        target == allowed or target.startswith(allowed + ".")
                        for allowed in SHARED_LAYER_IMPORTS[layer]):
                    violations.append(f"{module} ({layer}) imports {target}")
    assert not violations, "\n".join(sorted(violations))


def _reachable(graph, start):
    seen, todo = set(), [start]
    while todo:
        for target in graph.get(todo.pop(), ()):
            if target not in seen:
                seen.add(target)
                todo.append(target)
    return seen


def test_flight_log_readers_reach_neither_each_other_nor_the_dispatcher():
    """The format dispatch lives in ingest.log_formats, outside every reader: no reader imports another reader or
    the dispatcher, directly, deferred or through a package ``__init__``."""
    graph = architecture.import_graph(architecture.module_files())
    readers = {log_format.read.__module__ for log_format in log_formats.FORMATS}
    assert len(readers) == len(log_formats.FORMATS)
    violations = {reader: sorted(_reachable(graph, reader) & (readers - {reader} | {log_formats.__name__}))
                  for reader in sorted(readers)}
    assert not any(violations.values()), violations


def test_no_estimators_module_over_600_lines():
    long = {name: architecture.line_count(path) for name, path in architecture.module_files().items()
            if name.startswith("estimators") and architecture.line_count(path) > MAX_MODULE_LINES}
    assert not long, long


CITATION = re.compile(r"docs/([a-z_]+\.md), '([^']+)'")


def test_docstrings_cite_existing_docs_sections_and_nothing_outside_the_repository():
    """A citation ``docs/<file>.md, '<Section>'`` names a heading of that file; no citation of the design note
    that is not part of the repository ("math note 2.3", "design note section 8")."""
    headings = {path.name: {line.lstrip("#").strip() for line in path.read_text().splitlines() if line.startswith("#")}
                for path in (REPO_DIR / "docs").glob("*.md")}
    problems = []
    for package in (*sorted(ALLOWED), "tests", "benchmarks", "scripts"):
        for path in sorted((REPO_DIR / package).rglob("*.py")):
            text = path.read_text()
            for match in CITATION.finditer(text):
                title = re.sub(r"\s*\n\s*(#:?\s*)?", " ", match.group(2))  # a title wrapped over lines
                if title not in headings.get(match.group(1), ()):
                    problems.append(f"{path.relative_to(REPO_DIR)}: {match.group(0)} is not a heading")
            if path.name != "test_architecture.py" and re.search(r"\b(math|design) note\b", text, re.I):
                problems.append(f"{path.relative_to(REPO_DIR)} cites the design note")
    assert not problems, "\n".join(problems)


def test_a_cli_command_imports_its_own_stack_only():
    # `solarnav replay` must not pay for the simulator, Dask, the calibration stack or scipy.stats (seconds of
    # imports before the first line of work)
    code = ("import sys; from app.cli import build_parser; build_parser('replay'); "
            "print(sorted(m for m in ('sim.simulate', 'distributed', 'calib.calibration', 'scipy.stats', 'pvlib', "
            "'allantools') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_DIR, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    every = subprocess.run([sys.executable, "-c", code.replace("build_parser('replay')", "build_parser()")],
                           cwd=REPO_DIR, capture_output=True, text=True, check=True)
    assert "sim.simulate" in every.stdout  # the check sees them when they are imported
