"""The command line as one whole: every sub-command's parser walked for names, types and units."""
from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from runtime.cli import COMMANDS, build_parser, main
from runtime.commands.options import deprecated_options, positive_int, whole_number_at_least

ROOT = Path(__file__).resolve().parents[1]

# spellings replaced by one name per idea (still accepted, hidden, with a warning, for one release)
RETIRED = {"--frame-rate": "--camera-rate", "--rate": "--camera-rate", "--start": "--start-pose",
           "--pose": "--start-pose", "--version": "--fastslam"}
# a unit (or a word saying the number has none) in an option's metavar or help
UNIT = re.compile(r"\b(m|s|rad|Hz|px|m/s|rad/s|M|S|RAD|HZ|PX|M_S|RAD_S|metres|seconds|radians|"
                  r"fraction|ratio|factor|probability|sigmas?)\b")
FLOAT_TYPES = {"float", "finite_float", "positive_float", "non_negative_float"}


def walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) for every parser and sub-parser."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from walk(child, (*path, name))


def visible_options(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if action.help is argparse.SUPPRESS or not action.option_strings or isinstance(action, argparse._HelpAction):
            continue
        yield action


PARSERS = list(walk(build_parser()))


def test_every_command_is_registered_under_its_own_name():
    top = {path[0] for path, _ in PARSERS if path}
    assert top == set(COMMANDS)


@pytest.mark.parametrize(("path", "parser"), PARSERS, ids=[" ".join(p) or "p3at" for p, _ in PARSERS])
def test_options_use_one_name_per_idea_and_say_their_units(path, parser):
    for action in visible_options(parser):
        where = f"p3at {' '.join(path)} {action.option_strings[0]}"
        retired = set(action.option_strings) & set(RETIRED)
        assert not retired, f"{where}: {sorted(retired)} is spelled {RETIRED[sorted(retired)[0]]} elsewhere"
        if action.option_strings[0] == "--robot":
            # a robot's URL where a runtime connects to it, or a data set's robot number; never a world's robot
            assert re.search(r"URL|robot number|data set", f"{action.metavar} {action.help}"), where
        if getattr(action.type, "__name__", None) in FLOAT_TYPES:
            assert UNIT.search(f"{action.metavar or ''} {action.help or ''}"), f"{where}: which unit?"
        assert "degree" not in (action.help or "") and "°" not in (action.help or ""), f"{where}: radians, please"


def test_an_option_means_the_same_type_in_every_command():
    kinds: dict[str, set[str]] = {}
    for _path, parser in PARSERS:
        for action in visible_options(parser):
            kind = "flag" if action.nargs == 0 else getattr(action.type, "__name__", "str")
            kind = {**dict.fromkeys(FLOAT_TYPES, "number"), "Path": "text", "str": "text"}.get(kind, kind)
            kinds.setdefault(action.option_strings[0], set()).add(kind)
    mixed = {name: sorted(k) for name, k in kinds.items() if len(k) > 1 and name != "--robot"}
    assert not mixed, f"options whose type differs between commands: {mixed}"


def test_retired_spellings_are_still_accepted_but_hidden():
    hidden = {s for _path, parser in PARSERS for s in deprecated_options(parser)}
    assert {"--frame-rate", "--start", "--rate", "--pose", "--version", "--method"} <= hidden


def _in_fresh_interpreter(code: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a new Python (nothing imported yet), capturing its output."""
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_top_level_help_imports_no_command():
    code = ("import sys; from runtime.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('numpy', 'cv2', 'rerun', 'scipy') if m in sys.modules]\n"
            "sys.stderr.write(repr(heavy))")
    done = _in_fresh_interpreter(code)
    assert done.stderr.strip() == "[]"
    for name in COMMANDS:
        assert name in done.stdout


@pytest.mark.parametrize(("words", "option", "module"), [
    (["fuse"], "--preset", "runtime.commands.fuse"),
    (["slam", "dataset"], "--truth-heading", "runtime.commands.slam"),   # its work (slam_dataset) is not loaded
    (["demo"], "--processes", "runtime.commands.demo"),
    (["run"], "--robot", "runtime.commands.run"),   # its checks are mission_cli's, not demo's
])
def test_one_command_help_loads_only_that_command(words, option, module):
    code = ("import sys; from runtime.cli import main\n"
            f"try:\n    main({words + ['--help']!r})\nexcept SystemExit as stop:\n    status = stop.code\n"
            "loaded = sorted(m for m in sys.modules if m.startswith('runtime.commands.'))\n"
            "sys.stderr.write(repr((status, loaded)))")
    done = _in_fresh_interpreter(code)
    status, loaded = ast.literal_eval(done.stderr.strip())
    assert status == 0
    assert option in done.stdout
    assert set(loaded) - {"runtime.commands.options"} == {module}


@pytest.mark.parametrize("command", ["demo", "run"])
def test_a_mission_commands_help_imports_neither_the_mission_nor_numpy(command):
    """runtime/mission_cli.py imported runtime/mission.py, and so the whole stack (numpy, scipy, FastSLAM, fusion),
    to print ``p3at demo --help`` (1.4 s); the mission is imported when one runs."""
    code = ("import sys; from runtime.cli import main\n"
            f"try:\n    main([{command!r}, '--help'])\nexcept SystemExit:\n    pass\n"
            "sys.stderr.write(repr(sorted(m for m in sys.modules if m in ('numpy', 'runtime.mission', 'fusion', "
            "'estimation.fastslam', 'runtime.report'))))")
    done = _in_fresh_interpreter(code)
    assert done.stderr.strip() == "[]" and "--map-save-interval" in done.stdout


def test_a_closed_pipe_ends_quietly():
    """``p3at ... | head -1``: the reader goes away; no BrokenPipeError traceback."""
    code = ("import sys\nfrom runtime.cli import main\n"
            "import runtime.commands.calib as c\n"
            "sys.exit(main(['calib', 'show', sys.argv[1]]))")
    ini = ROOT / "mocks" / "stereo_head" / "data" / "sth_mdcs2_default.ini"
    if not ini.is_file():
        pytest.skip("the virtual head's calibration file is not installed")
    producer = subprocess.Popen([sys.executable, "-c", code, str(ini)], cwd=ROOT, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
    producer.stdout.close()  # the reader is gone before the first line is written
    _out, err = producer.communicate(timeout=120)
    assert b"Traceback" not in err and b"BrokenPipe" not in err


def test_errors_are_one_line_with_the_documented_exit_status(tmp_path, capsys):
    assert main(["fuse", str(tmp_path / "absent.npz"), str(tmp_path / "b.npz"), "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "absent.npz" in err and "Traceback" not in err


@given(low=st.integers(-5, 5), value=st.integers(-10**6, 10**6))
def test_a_whole_number_at_least_low_accepts_exactly_the_integers_from_low(low, value):
    parse = whole_number_at_least(low)
    if value >= low:
        assert parse(str(value)) == value
    else:
        with pytest.raises(argparse.ArgumentTypeError, match=f">= {low}"):
            parse(str(value))


@pytest.mark.parametrize("text", ["", "1.5", "1e3", "two", "nan"])
def test_a_whole_number_refuses_what_is_not_one(text):
    for parse in (positive_int, whole_number_at_least(2)):
        with pytest.raises(argparse.ArgumentTypeError, match="expected a whole number"):
            parse(text)


def test_positive_int_is_the_shared_whole_number_type_from_one():
    assert positive_int("1") == 1 and positive_int.__name__ == "positive_int"
    with pytest.raises(argparse.ArgumentTypeError, match=">= 1"):
        positive_int("0")


def test_scanmatch_limit_uses_the_shared_type_and_says_the_bound(tmp_path, capsys):
    log = tmp_path / "empty.log"
    log.write_text("")
    assert main(["scanmatch", str(log), "--limit", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--limit" in err and "expected a whole number >= 2, not '1'" in err


def test_benchmark_options_parse_numbers_with_the_shared_types():
    """A benchmark's `--particles 0` or `--seconds nan` is refused with the domain, as in `p3at`: no option of a
    benchmark script is typed bare int or float (read from the source, nothing imported)."""
    bare = {}
    for script in sorted((ROOT / "benchmarks").glob("*.py")):
        text = script.read_text()
        if not re.search(r"\btype\s*=\s*(int|float)\b", text):  # parse only the scripts that might have one
            continue
        for node in ast.walk(ast.parse(text, str(script))):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "add_argument":
                for keyword in node.keywords:
                    if keyword.arg == "type" and isinstance(keyword.value, ast.Name) \
                            and keyword.value.id in ("int", "float"):
                        bare.setdefault(script.name, []).append(ast.literal_eval(node.args[0]))
    assert not bare, bare
