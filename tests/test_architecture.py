"""The layer rule: ingest -> calib -> estimators -> (sim, app); no computation layer imports the UI toolkits."""

from __future__ import annotations

import ast

import pytest

from tests.conftest import REPO_DIR

#: What each top-level package may import from the project.
ALLOWED = {
    "ingest": {"ingest"},
    "calib": {"ingest", "calib"},
    "estimators": {"ingest", "calib", "estimators"},
    "sim": {"ingest", "calib", "estimators", "sim"},
    "app": {"ingest", "calib", "estimators", "sim", "app"},
}
PROJECT_PACKAGES = set(ALLOWED)
UI_MODULES = {"streamlit", "plotly", "tsdownsample"}


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
    assert not violations, "\n".join(violations)
