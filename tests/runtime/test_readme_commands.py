"""The commands README.md and the user docs show exist as shown: every ``p3at ...`` they write names a sub-command the
CLI has and only options that sub-command takes, and every command line of a ``sh`` block parses as typed.

The lines are read from the documents themselves, so a renamed option or sub-command fails here rather than in a
user's shell. (The history notebooks, docs/*-history.md, are a record of their time and are not checked.)"""
from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import pytest

from runtime.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = ["README.md"] + sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")
                                   if not p.name.endswith("-history.md"))
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def _fenced_commands(text: str) -> list[tuple[str, str]]:
    """(fence language, line) for every line of a fenced block that starts with ``p3at``."""
    found, fence = [], None
    for line in text.splitlines():
        if line.startswith("```"):
            fence = None if fence is not None else line[3:].strip()
        elif fence is not None and line.lstrip().startswith("p3at "):
            found.append((fence, line.strip()))
    return found


def _without_comment(line: str) -> str:
    return re.split(r"\s#", line, maxsplit=1)[0].strip()


def _shown_commands() -> list[tuple[str, str, bool]]:
    """(document, command, typed) for every p3at command the documents show; typed: a line of an ``sh`` block."""
    shown = []
    for name in DOCUMENTS:
        text = (ROOT / name).read_text(encoding="utf-8")
        for fence, line in _fenced_commands(text):
            shown.append((name, _without_comment(line), fence == "sh"))
        for span in re.findall(r"`(p3at [^`\n]*)`", text):
            shown.append((name, span.split(":")[0] if ": " in span else span, False))
    return shown


SHOWN = _shown_commands()
TYPED = [(doc, line) for doc, line, typed in SHOWN if typed]
PARSER = build_parser()


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _options(parser: argparse.ArgumentParser) -> set[str]:
    """The options --help lists: a hidden deprecated spelling still works but is not to be taught."""
    return {s for action in parser._actions if action.help != argparse.SUPPRESS for s in action.option_strings}


def _commands_named(words: list[str]) -> list[tuple[str, argparse.ArgumentParser]]:
    """The (sub-)commands the words after ``p3at`` name, deepest first level reached; ``run/demo`` and
    ``info|drive`` name several."""
    level = [("p3at", PARSER)]
    for word in words:
        if word.startswith("-"):
            break
        alternatives = re.split(r"[/|]", word)
        children = [(f"{name} {alt}", _subparsers(parser).get(alt)) for name, parser in level for alt in alternatives]
        if not all(child is not None for _, child in children):
            break
        level = children
    return level


def test_the_documents_show_commands():
    # the checks below would pass on documents that lost their commands
    assert len(TYPED) >= 15 and len(SHOWN) >= 100
    assert {doc for doc, _ in TYPED} >= {"README.md", "docs/runtime.md", "docs/fleet.md", "docs/fastslam.md"}


@pytest.mark.parametrize(("document", "command"), sorted({(d, c) for d, c, _ in SHOWN}))
def test_every_shown_command_and_option_exists(document, command):
    words = command.split()[1:]
    named = _commands_named(words)
    assert named != [("p3at", PARSER)] or not words or words[0].startswith("-") or words[0] == "...", (
        f"{document}: {command!r}: no sub-command {words[0]!r}")
    for name, parser in named:
        unknown = sorted(set(OPTION.findall(command)) - _options(parser))
        assert not unknown, f"{document}: {command!r}: {name} has no option {', '.join(unknown)}"


@pytest.mark.parametrize(("document", "command"), TYPED)
def test_every_typed_command_line_parses(document, command):
    words = [w for w in shlex.split(command)[1:] if not (w.startswith("[") and w.endswith("]"))]
    try:
        PARSER.parse_args(words)
    except Exception as e:  # the CLI's one-line usage error
        pytest.fail(f"{document}: {command!r} does not parse: {e}")


@pytest.mark.parametrize("command", sorted({c.split()[1] for _, c, _ in SHOWN if len(c.split()) > 1
                                            and c.split()[1] in _subparsers(PARSER)}))
def test_every_named_command_answers_help(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0 and f"usage: p3at {command}" in capsys.readouterr().out


def _fenced_make(text: str) -> list[str]:
    found, fence = [], None
    for line in text.splitlines():
        if line.startswith("```"):
            fence = None if fence is not None else line[3:].strip()
        elif fence is not None and re.match(r"make [\w./-]+", line.strip()):
            found.append(line.strip().split()[1])
    return found


def test_every_make_target_the_documents_name_is_in_the_makefile():
    targets = set(re.findall(r"^([\w./$()-]+):", (ROOT / "Makefile").read_text(encoding="utf-8"), re.MULTILINE))
    named = set()
    for name in DOCUMENTS:
        text = (ROOT / name).read_text(encoding="utf-8")
        named |= set(re.findall(r"`make ([\w./-]+)", text)) | set(_fenced_make(text))
    assert {"demo", "test", "bench"} <= named, named
    assert named <= targets, f"not in the Makefile: {sorted(named - targets)}"
