"""The user's Zenoh configuration (``--exchange zenoh:FILE`` or inline JSON5) against nesting and size.

Zenoh's parser recurses per level of nesting in native code: a configuration nested ~30 000 deep (a 60 kB file,
or an inline argument) killed p3at with SIGSEGV, no message and no cleanup. make_config now refuses more than
MAX_CONFIG_DEPTH levels (counted outside quoted strings) and more than MAX_CONFIG_BYTES before Zenoh parses it.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from runtime.fleet.zenoh_exchange import MAX_CONFIG_BYTES, MAX_CONFIG_DEPTH, ExchangeError, make_config

REPO = Path(__file__).resolve().parents[2]


def _nested(depth: int, inside: str = "1") -> str:
    """A valid configuration whose free-form metadata is ``depth`` lists deep (the whole is depth + 2 deep)."""
    return "{mode: 'peer', metadata: {a: " + "[" * depth + inside + "]" * depth + "}}"


@pytest.mark.parametrize("inline", [True, False])
def test_a_configuration_nested_beyond_what_zenoh_survives_is_one_line_not_a_crash(tmp_path, inline):
    """In a child process: on a tree without the bound the parser's stack overflow kills the process (SIGSEGV),
    which must fail this test, not end the test run."""
    text = _nested(40_000)
    path = tmp_path / "deep.json5"
    path.write_text(text)
    argument = text if inline else str(path)
    code = ("import sys\nfrom runtime.fleet.zenoh_exchange import ExchangeError, make_config\n"
            "try:\n    make_config(sys.argv[1], 'fusion')\nexcept ExchangeError as e:\n    print(e)\n")
    done = subprocess.run([sys.executable, "-c", code, argument], capture_output=True, text=True, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=300)
    assert done.returncode == 0, f"make_config ended the process: status {done.returncode}"
    line = done.stdout.strip()
    assert "\n" not in line and line.endswith(f"nested 40002 levels deep; a Zenoh configuration has at most "
                                              f"{MAX_CONFIG_DEPTH}")
    assert line.startswith(str(path) if not inline else "{mode: 'peer'")


def test_a_configuration_file_larger_than_the_bound_is_refused_before_parsing(tmp_path):
    path = tmp_path / "big.json5"
    path.write_text("{mode: 'peer', metadata: {a: '" + "x" * MAX_CONFIG_BYTES + "'}}")
    with pytest.raises(ExchangeError, match=rf"big\.json5: \d+ bytes; a Zenoh configuration is a few kB \(at most "
                                            rf"{MAX_CONFIG_BYTES}\)"):
        make_config(str(path), "fusion")


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(depth=st.integers(min_value=0, max_value=3 * MAX_CONFIG_DEPTH),
       decoy=st.text(alphabet="[]{}'\\ab", max_size=200), as_file=st.booleans())
@example(depth=MAX_CONFIG_DEPTH - 2, decoy="[" * 500, as_file=True)   # the deepest accepted
@example(depth=MAX_CONFIG_DEPTH - 1, decoy="", as_file=False)         # one level more: refused
def test_depth_is_counted_outside_strings(tmp_path, depth, decoy, as_file):
    """Brackets inside a quoted string (with escapes) do not count; the configuration's own levels do."""
    quoted = '"' + decoy.replace("\\", "\\\\").replace('"', '\\"') + '"'
    text = _nested(depth, quoted)
    path = tmp_path / "c.json5"
    path.write_text(text)
    if depth + 2 > MAX_CONFIG_DEPTH:
        with pytest.raises(ExchangeError, match=f"nested {depth + 2} levels deep"):
            make_config(str(path) if as_file else text, "fusion")
    else:
        make_config(str(path) if as_file else text, "fusion")   # a Zenoh Config: the bound refuses nothing valid
