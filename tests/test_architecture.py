"""Rules import-linter cannot express: inside runtime, only runtime/rerun_sdk.py imports rerun."""
from __future__ import annotations

import ast
import functools
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("drivers", "estimation", "fusion", "mocks", "runtime")


@functools.cache
def _imported_modules(path: Path) -> frozenset[str]:
    """The top-level packages ``path`` imports anywhere in it; parsed once per process (both tests below read every
    module's: about a second each, parsing the tree)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return frozenset(names)


def _imports_at_import_time(path: Path) -> set[str]:
    """The top-level packages a module imports as it is imported (its module-level statements, ``try`` and ``if``
    blocks included; not the imports inside its functions)."""
    names = set()
    pending = list(ast.parse(path.read_text(), filename=str(path)).body)
    while pending:
        node = pending.pop()
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
        elif isinstance(node, ast.If | ast.Try | ast.With):
            pending += [child for child in ast.iter_child_nodes(node) if isinstance(child, ast.stmt)]
            pending += [stmt for handler in getattr(node, "handlers", []) for stmt in handler.body]
    return names


def test_only_runtime_rerun_sdk_imports_rerun():
    """runtime/rerun_sdk.py imports rerun (once, with its RUST_LOG); the other Rerun modules take ``rr`` from it, and
    only the reader imports ``rerun.chunk``, inside the function that reads (rerun_sdk imported before it)."""
    importers = sorted(
        str(path.relative_to(ROOT))
        for package in PACKAGES
        for path in (ROOT / package).rglob("*.py")
        if "rerun" in _imported_modules(path)
    )
    at_import = [path for path in importers if "rerun" in _imports_at_import_time(ROOT / path)]
    assert at_import == ["runtime/rerun_sdk.py"]
    assert importers == ["runtime/rerun_read.py", "runtime/rerun_sdk.py"]


def test_no_pickle_anywhere():
    offenders = sorted(
        str(path.relative_to(ROOT))
        for package in PACKAGES
        for path in (ROOT / package).rglob("*.py")
        if {"pickle", "cPickle", "dill", "joblib"} & _imported_modules(path) or "allow_pickle=True" in path.read_text()
    )
    assert offenders == []
