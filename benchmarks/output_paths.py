"""Where a benchmark may write: never into the data set it reads (a user's copy of MRCLAM is their data). The check
is the commands' own (``runtime.commands.options.check_output_apart``); this module words it as a script's error."""
from __future__ import annotations

from pathlib import Path

from runtime.commands.options import OutputPathError, check_output_apart


def output_refusal(script: str, option: str, out: Path | None, data: Path) -> str | None:
    """The one-line error for an output folder given by ``option`` that is the data set folder ``data`` or lies
    inside it (links and ``..`` resolved), else None (also when no output folder was given)."""
    try:
        check_output_apart(out, option, folders={"data set": data})
    except OutputPathError as e:
        return f"{script}: error: {e}"
    return None
