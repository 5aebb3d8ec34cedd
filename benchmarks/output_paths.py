"""Where a benchmark may write: never into the data set it reads (a user's copy of MRCLAM is their data)."""
from __future__ import annotations

from pathlib import Path


def output_inside_input(out: Path, data: Path) -> bool:
    """True when the folder ``out`` is the folder ``data`` or inside it (symbolic links and ``..`` resolved)."""
    return Path(out).resolve().is_relative_to(Path(data).resolve())


def output_refusal(script: str, option: str, out: Path | None, data: Path) -> str | None:
    """The one-line error for an output folder given by ``option`` inside the data set folder ``data``, else None
    (also when no output folder was given)."""
    if out is None or not output_inside_input(out, data):
        return None
    return (f"{script}: error: {option} {out} is inside the data set folder --data {data}; "
            "choose an output folder outside it")
