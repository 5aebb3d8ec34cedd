"""Rerun itself, imported once and quietly: the one module of the project that imports ``rerun``.

Pinned to rerun-sdk 0.41. The Rerun modules take ``rr`` and ``rrb`` from here (``from runtime.rerun_sdk import rr``),
so that whichever is imported first, Rerun is imported with the RUST_LOG below; the reader imports ``rerun.chunk``
inside the function that reads, after this module.

The Rerun modules, each one job (each imports only modules above it in this list):

- runtime/rerun_sdk.py: Rerun itself;
- runtime/rerun_watch.py: whether a saved recording's writer still writes and a live viewer still listens (no Rerun);
- runtime/rerun_sink.py: where a recording goes (a saved file, a viewer it starts, a viewer's URL, memory);
- runtime/rerun_style.py: how it looks (colours, legend names, the layouts);
- runtime/rerun_map_format.py: what the writer and the reader agree on (a map snapshot's arrays and checksum, the
  entity that marks a closed recording);
- runtime/rerun_rows.py: :class:`RowSender`, how the per-frame rows reach the stream (live, or batched to a file);
- runtime/rerun_log.py: :class:`MissionLog`, what a mission logs (its docstring lists the entity tree);
- runtime/rerun_read.py: :func:`read_recording`, reading a saved recording back (``p3at review``).
"""
from __future__ import annotations

import os

# Saved recordings are written without Rerun's footer (see open_recording in runtime/rerun_sink.py), and Rerun warns
# once per file that it opts out of one. Rerun reads RUST_LOG once, when it is imported: when the user set none,
# import it with the Python SDK's default level ("warn": a plain import prints no INFO line) and that one warning
# silenced, then unset it again so that child processes (a spawned viewer) get their plain default. A RUST_LOG the
# user set is kept.
QUIET_FOOTER_WARNING = "warn,re_log_encoding::rrd::file_sink=error"
_users_rust_log = os.environ.get("RUST_LOG")
if _users_rust_log is None:
    os.environ["RUST_LOG"] = QUIET_FOOTER_WARNING
try:
    import rerun as rr
    import rerun.blueprint as rrb
finally:
    if _users_rust_log is None:
        os.environ.pop("RUST_LOG", None)

__all__ = ["QUIET_FOOTER_WARNING", "rr", "rrb"]
