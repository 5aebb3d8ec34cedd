"""benchmarks/eval_fusion.py's MRCLAM folder (session 24's leftover, session 25, C): its default is found from the
script's place, so that a run from any folder reads the same data set, and a folder given by name that is not there
is an error (exit 2) rather than its tables silently skipped."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "eval_fusion.py"
DEFAULT = SCRIPT.parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"


def _run(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *argv], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_a_missing_mrclam_folder_given_by_name_is_an_error(tmp_path) -> None:
    done = _run("--mrclam", "no-such-folder", cwd=tmp_path)
    assert done.returncode == 2 and "--mrclam no-such-folder: not a folder" in done.stderr, done.stderr
    assert done.stdout == ""   # refused before any table


def test_the_default_folder_is_the_same_from_any_working_folder(tmp_path) -> None:
    helps = [" ".join(_run("--help", cwd=cwd).stdout.split()) for cwd in (tmp_path, SCRIPT.parent)]
    # (DEFAULT itself, not resolved: a ../shared that is a symbolic link stays the path the script names)
    assert helps[0] == helps[1] and f"default {DEFAULT}" in helps[0]
