"""Rules import-linter cannot express: inside runtime, only the Rerun module talks to rerun."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("drivers", "estimation", "fusion", "mocks", "runtime")


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_only_runtime_rerun_log_imports_rerun():
    importers = sorted(
        str(path.relative_to(ROOT))
        for package in PACKAGES
        for path in (ROOT / package).rglob("*.py")
        if "rerun" in _imported_modules(path)
    )
    assert importers == ["runtime/rerun_log.py"]


def test_no_pickle_anywhere():
    offenders = sorted(
        str(path.relative_to(ROOT))
        for package in PACKAGES
        for path in (ROOT / package).rglob("*.py")
        if {"pickle", "cPickle", "dill", "joblib"} & _imported_modules(path) or "allow_pickle=True" in path.read_text()
    )
    assert offenders == []
