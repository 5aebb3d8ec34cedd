"""Every number option of ``p3at`` states its domain: a value outside it ends in one line naming the option and
the allowed range (exit 2) before anything runs, and the edge values the help documents are accepted.

Nothing here starts a mission or opens a device: ``main`` runs with every command's handler replaced by one that
only records the parsed arguments.
"""
from __future__ import annotations

import argparse
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

import runtime.cli as cli
from runtime.commands.camera import _guid, _usb_id
from runtime.commands.options import (
    finite_float,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
)
from runtime.commands.robot import tcp_port
from runtime.mission_cli import camera_latency

# the least a command needs besides the option under test (none of it is read: the handler never runs)
BASE = {
    "run": ["run"], "demo": ["demo"],
    "robot info": ["robot", "info", "socket://127.0.0.1:1"],
    "robot drive": ["robot", "drive", "socket://127.0.0.1:1", "--seconds", "1"],
    "robot serve": ["robot", "serve"],
    "camera info": ["camera", "info"], "camera grab": ["camera", "grab", "--out", "frames"],
    "features": ["features", "l.png", "r.png", "--out", "m.csv"],
    "slam simulate": ["slam", "simulate", "--out", "m.npz"],
    "slam dataset": ["slam", "dataset", "mrclam", "data", "--robot", "1", "--out", "m.npz"],
    "slam noise": ["slam", "noise", "mrclam", "data", "--robot", "1", "--out", "n.toml"],
    "fuse": ["fuse"], "scanmatch": ["scanmatch", "scans.log"], "replay": ["replay", "log"],
}
MISSION = ("run", "demo")

# (command, option, refused value, what the message says the domain is)
REFUSED = [
    *[(c, "--robots", v, ">= 1") for c in MISSION for v in ("0", "-1", "1.5", "two")],
    *[(c, "--seconds", v, "> 0") for c in MISSION for v in ("-5", "0", "nan", "inf", "-inf")],
    *[(c, "--seed", v, ">= 0") for c in MISSION for v in ("-1", "0.5")],
    *[(c, "--camera-rate", v, "> 0") for c in MISSION for v in ("0", "nan")],
    *[(c, "--camera-latency", v, "[0, 1)") for c in MISSION for v in ("-0.01", "1", "nan", "inf", "x")],
    *[(c, "--particles", v, ">= 1") for c in MISSION for v in ("0", "-3")],
    *[(c, "--max-corners", v, ">= 1") for c in MISSION for v in ("0", "-1")],
    *[(c, "--max-observations", v, ">= 0") for c in MISSION for v in ("-1", "nan")],
    *[(c, "--speed", v, "> 0") for c in MISSION for v in ("0", "-0.3", "inf")],
    *[(c, "--fusion-interval", v, ">= 0") for c in MISSION for v in ("-1", "nan")],
    *[(c, "--time-scale", v, "> 0") for c in MISSION for v in ("0", "nan", "-2")],
    *[(c, "--map-save-interval", v, ">= 0") for c in MISSION for v in ("-10", "inf")],
    *[(c, "--baud", "0", ">= 1") for c in ("robot info", "robot drive")],
    *[(c, "--link-timeout", v, "> 0") for c in ("robot info", "robot drive") for v in ("0", "nan")],
    ("robot drive", "--vel", "nan", "finite"), ("robot drive", "--rvel", "-inf", "finite"),
    ("robot drive", "--seconds", "-5", "> 0"), ("robot drive", "--every", "0", "> 0"),
    ("robot serve", "--tcp", "70000", "0 to 65535"), ("robot serve", "--tcp", "-1", "0 to 65535"),
    ("robot serve", "--tcp", "http", "0 to 65535"),
    ("robot serve", "--time-scale", "0", "> 0"), ("robot serve", "--seed", "-1", ">= 0"),
    ("robot serve", "--duration", "-1", ">= 0"), ("robot serve", "--duration", "nan", ">= 0"),
    *[(c, o, v, "0 to ffff") for c in ("camera info", "camera grab") for o in ("--vendor-id", "--product-id")
      for v in ("-1", "10000", "zz")],
    *[(c, "--guid", "1" + "0" * 16, "0 to ffffffffffffffff") for c in ("camera info", "camera grab")],
    *[(c, "--seed", "-1", ">= 0") for c in ("camera info", "camera grab")],
    ("camera grab", "--camera-rate", "0", "> 0"), ("camera grab", "--timeout", "nan", "> 0"),
    ("features", "--fx", "0", "> 0"), ("features", "--fy", "-1", "> 0"), ("features", "--cx", "nan", "finite"),
    ("features", "--cy", "inf", "finite"), ("features", "--baseline", "0", "> 0"),
    ("features", "--max-disparity", "-1", "> 0"),
    ("slam simulate", "--seconds", "-5", "> 0"), ("slam simulate", "--seed", "-1", ">= 0"),
    ("slam simulate", "--particles", "0", ">= 1"), ("slam simulate", "--camera-rate", "nan", "> 0"),
    ("slam dataset", "--robot", "0", ">= 1"), ("slam dataset", "--particles", "0", ">= 1"),
    ("slam dataset", "--seed", "-1", ">= 0"), ("slam dataset", "--until", "0", "> 0"),
    *[("slam dataset", "--seeds", v, "two or more distinct seeds") for v in ("1", "0,0")],
    ("slam noise", "--robot", "0", ">= 1"), ("slam noise", "--window", "nan", "> 0"),
    # one word: too few numbers (two different ids, distance/sigma <= 0, the log's ids: its own test file)
    *[("slam noise", "--known-distance", v, d) for v, d in (("0", "ID1 ID2 METRES [SIGMA]"),
                                                              ("-2", "ID1 ID2 METRES [SIGMA]"),
                                                              ("nan", "a finite number"))],
    ("fuse", "--seed", "-1", ">= 0"), ("fuse", "--interval", "0", "> 0"), ("fuse", "--min-period", "-1", ">= 0"),
    ("fuse", "--seconds", "-5", ">= 0"),
    *[("fuse", "--start-sigma", v, "two positive numbers") for v in ("0,0.3", "1,-0.3", "nan,0.3", "1", "1,x")],
    *[(c, "--start-prior", v, "two positive numbers") for c in MISSION for v in ("0,0.3", "inf,0.3", "1,2,3")],
    ("scanmatch", "--step", "0", ">= 1"), ("scanmatch", "--max-distance", "nan", "> 0"),
    ("scanmatch", "--limit", "1", ">= 2"),
    ("replay", "--particles", "0", ">= 1"), ("replay", "--seed", "-1", ">= 0"),
    # a typed option that is not a number: the walk below sees it, and its refusal is tested the same way
    *[(c, "--recording-id", v, "printable text of 1 to 256 characters") for c in (*MISSION, "fuse") for v in ("", " ")],
]

# (command, option, documented edge value, the value the command gets)
ACCEPTED = [
    *[(c, "--robots", "1", 1) for c in MISSION],
    *[(c, "--seed", "0", 0) for c in MISSION],
    *[(c, "--camera-latency", v, float(v)) for c in MISSION for v in ("0", "0.999")],
    *[(c, "--max-observations", "0", 0) for c in MISSION],            # 0: all
    *[(c, "--fusion-interval", "0", 0.0) for c in MISSION],           # 0: at the end only
    *[(c, "--map-save-interval", "0", 0.0) for c in MISSION],         # 0: at the end only
    *[(c, "--seconds", "1e-3", 1e-3) for c in MISSION],
    ("robot drive", "--vel", "-0.5", -0.5), ("robot drive", "--rvel", "-1", -1.0),
    ("robot serve", "--tcp", "0", 0), ("robot serve", "--tcp", "65535", 65535),  # 0: any free port
    ("robot serve", "--duration", "0", 0.0),
    ("camera info", "--vendor-id", "ffff", 0xFFFF), ("camera info", "--product-id", "0", 0),
    ("camera info", "--guid", "f" * 16, 2**64 - 1),
    ("features", "--cx", "-3.5", -3.5),
    ("fuse", "--seconds", "0", 0.0), ("fuse", "--min-period", "0", 0.0),   # 0: until stopped; no minimum
    ("scanmatch", "--limit", "2", 2),
]


@pytest.fixture
def parse_only(monkeypatch):
    """``main`` as the user runs it, with handlers that only collect the parsed arguments."""
    parsed: list[argparse.Namespace] = []
    real = cli.build_parser

    def build(commands=None):
        parser = real(commands)
        for sub in _parsers(parser):
            if sub.get_default("handler") is not None:
                sub.set_defaults(handler=parsed.append)
        return parser

    monkeypatch.setattr(cli, "build_parser", build)
    return parsed


def _parsers(parser: argparse.ArgumentParser):
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                yield from _parsers(child)


def _number_options():
    """(command, option) of every visible option of the whole CLI that parses a number."""
    def walk(parser, path):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, child in action.choices.items():
                    yield from walk(child, (*path, name))
            elif (action.option_strings and action.help is not argparse.SUPPRESS and action.type is not None
                  and getattr(action.type, "__name__", "") not in ("str", "Path") and action.choices is None):
                yield " ".join(path), action.option_strings[0]
    return set(walk(cli.build_parser(), ()))


@pytest.mark.parametrize(("command", "option", "value", "domain"), REFUSED,
                         ids=[f"{c} {o}={v}" for c, o, v, _ in REFUSED])
def test_a_value_outside_the_domain_is_one_line_naming_option_and_range(parse_only, capsys, command, option,
                                                                         value, domain):
    status = cli.main([*BASE[command], f"{option}={value}"])
    err = capsys.readouterr().err
    assert status == 2, err
    assert not parse_only, "the command ran"
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"p3at {command}: argument {option}") and domain in err and repr(value) in err, err


@pytest.mark.parametrize(("command", "option", "value", "expected"), ACCEPTED,
                         ids=[f"{c} {o}={v}" for c, o, v, _ in ACCEPTED])
def test_the_documented_edge_values_are_accepted(parse_only, capsys, command, option, value, expected):
    assert cli.main([*BASE[command], option, value]) == 0, capsys.readouterr().err
    got = getattr(parse_only[0], option.lstrip("-").replace("-", "_"))
    assert got == expected and type(got) is type(expected)


def test_every_number_option_has_a_refused_case_and_no_bare_int_or_float():
    options = _number_options()
    assert ("run", "--seconds") in options and ("robot serve", "--tcp") in options  # the walk sees the CLI
    assert options <= {(c, o) for c, o, _, _ in REFUSED}, "number options without a refused value above"
    parser = cli.build_parser()  # once: building it per option was most of this test's time
    bare = {(c, o) for c, o in options
            for a in [_action(parser, c, o)] if a.type in (int, float)}
    assert not bare, f"options typed bare int/float, whose domain the user is not told: {sorted(bare)}"


def _action(parser: argparse.ArgumentParser, command: str, option: str) -> argparse.Action:
    for word in command.split():
        parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[word]
    return next(a for a in parser._actions if option in a.option_strings)


@pytest.mark.parametrize("command", sorted(BASE))
def test_help_states_every_command_and_exits_zero(parse_only, capsys, command):
    with pytest.raises(SystemExit) as stop:
        cli.main([*command.split(), "--help"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: p3at {command}")


# ---------------------------------------------------------------------------------------------- the types
FLOAT_TYPES = [(finite_float, lambda v: True), (positive_float, lambda v: v > 0),
               (non_negative_float, lambda v: v >= 0), (camera_latency, lambda v: 0 <= v < 1)]
INT_TYPES = [(positive_int, lambda v: v >= 1), (non_negative_int, lambda v: v >= 0),
             (tcp_port, lambda v: 0 <= v <= 65535)]


@pytest.mark.parametrize(("parse", "inside"), FLOAT_TYPES, ids=[t.__name__ for t, _ in FLOAT_TYPES])
@given(value=st.floats(allow_nan=True, allow_infinity=True))
def test_a_float_type_accepts_exactly_the_finite_numbers_of_its_domain(parse, inside, value):
    if math.isfinite(value) and inside(value):
        assert parse(repr(value)) == value
    else:
        with pytest.raises(argparse.ArgumentTypeError):
            parse(repr(value))


@pytest.mark.parametrize(("parse", "inside"), FLOAT_TYPES + INT_TYPES,
                         ids=[t.__name__ for t, _ in FLOAT_TYPES + INT_TYPES])
@given(text=st.text(max_size=12) | st.from_regex(r"\A[ +-]?[0-9_.eE]{1,8}\Z"))
def test_any_text_is_either_a_value_of_the_domain_or_an_argument_type_error(parse, inside, text):
    try:
        value = parse(text)
    except argparse.ArgumentTypeError as error:
        assert repr(text) in str(error)
        return
    assert inside(value) and math.isfinite(value)


@pytest.mark.parametrize(("parse", "inside"), INT_TYPES, ids=[t.__name__ for t, _ in INT_TYPES])
@given(value=st.integers(-2**70, 2**70))
def test_an_int_type_accepts_exactly_the_whole_numbers_of_its_domain(parse, inside, value):
    if inside(value):
        assert parse(str(value)) == value
    else:
        with pytest.raises(argparse.ArgumentTypeError):
            parse(str(value))


@pytest.mark.parametrize(("parse", "high"), [(_usb_id, 0xFFFF), (_guid, 2**64 - 1)], ids=["usb_id", "guid"])
@given(value=st.integers(-2**66, 2**66))
def test_a_hex_id_accepts_exactly_what_fits_its_bits(parse, high, value):
    text = format(value, "x")
    if 0 <= value <= high:
        assert parse(text) == value
    else:
        with pytest.raises(argparse.ArgumentTypeError, match=f"0 to {high:x}"):
            parse(text)
