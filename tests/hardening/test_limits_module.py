"""The limits the command line and the runtime's modules share live in ``runtime.limits`` (session 26, C). Before,
runtime/rerun_log.py imported ``RERUN_URL_PREFIXES`` and runtime/sensorlog.py ``MAX_PARTICLES`` from the CLI layer
(runtime/commands/options.py): a runtime module depended on the command line."""
from __future__ import annotations

import ast
from pathlib import Path

import runtime.commands.options as options
import runtime.limits as limits

RUNTIME = Path(__file__).resolve().parents[2] / "runtime"
# the command-line layer: argument parsing, the commands, the options of the commands
CLI_LAYER = {"cli.py", "mission_cli.py", "fleet/options.py"}


def _imported(path: Path) -> set[str]:
    """Every module ``path`` imports (``from X import Y`` gives X and X.Y), at its top or inside a function."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names |= {node.module} | {f"{node.module}.{alias.name}" for alias in node.names}
    return names


def test_no_runtime_module_outside_the_command_line_imports_it() -> None:
    offenders = {}
    for path in sorted(RUNTIME.rglob("*.py")):
        where = path.relative_to(RUNTIME).as_posix()
        if where.startswith("commands/") or where in CLI_LAYER:
            continue
        cli = sorted(n for n in _imported(path) if n.startswith("runtime.commands") or n == "runtime.cli")
        if cli:
            offenders[where] = cli
    assert offenders == {}


def test_the_limits_module_imports_nothing_and_the_cli_checks_the_same_values() -> None:
    assert _imported(Path(limits.__file__)) <= {"__future__", "__future__.annotations"}
    assert options.MAX_PARTICLES is limits.MAX_PARTICLES
    assert options.particle_count(str(limits.MAX_PARTICLES)) == limits.MAX_PARTICLES
    assert options.RERUN_URL_PREFIXES is limits.RERUN_URL_PREFIXES
