"""Every alignment decision of an evaluation run, recorded exactly, and two recordings compared (session 23).

A change meant to make fusion cheaper must not move a decision. ``record`` runs ``benchmarks/eval_fusion.py`` of the
tree ROOT (any checkout: an old commit's git worktree, with this venv) and writes one JSON line per call of
``fusion.align`` / ``fusion.align_at`` (found, reason, supports, pose, covariances, every statistic) and per decoy
chance rate, floats as exact hexadecimal; ``compare`` reports every record that differs (poses, covariances and float
statistics beyond a relative 1e-9, everything else exactly) and exits 1 if any does::

    .venv/bin/python benchmarks/fusion_decisions.py record /tmp/old old.jsonl -- --trust-only --false-pairs 1000
    .venv/bin/python benchmarks/fusion_decisions.py record . new.jsonl -- --trust-only --false-pairs 1000
    .venv/bin/python benchmarks/fusion_decisions.py compare old.jsonl new.jsonl
"""
from __future__ import annotations

import argparse
import json
import runpy
import sys
from pathlib import Path

import numpy as np


def _hex(values) -> list[str] | None:
    return None if values is None else [float.hex(float(v)) for v in np.ravel(values)]


def record(root: Path, out: Path, eval_args: list[str]) -> None:
    """Run ROOT's eval_fusion.py with ``eval_args``, every align / align_at / decoy rate written to ``out``."""
    root = root.resolve()
    sys.path[:0] = [str(root), str(root / "benchmarks")]
    import importlib

    import fusion.alignment as alignment
    import fusion.evidence as evidence
    if not Path(alignment.__file__).resolve().is_relative_to(root):
        raise SystemExit(f"fusion imported from {alignment.__file__}, not from {root}")
    log = out.open("w")

    def write(kind: str, fields: dict) -> None:
        log.write(json.dumps({"k": kind, **fields}, default=repr) + "\n")

    def recorded(fn, kind: str):
        def wrapper(*args, **kwargs):
            a = fn(*args, **kwargs)
            stats = {k: float.hex(v) if isinstance(v, float) else v for k, v in a.statistics.to_dict().items()}
            write(kind, {"found": a.found, "reason": a.reason, "pose": _hex(a.pose), "cov": _hex(a.covariance),
                         "start": _hex(a.start_covariance), "supports": a.supports.tolist(), "stats": stats})
            return a
        return wrapper

    decoy_rate = evidence.decoy_chance_supports

    def decoys(*args, **kwargs):
        rate = decoy_rate(*args, **kwargs)
        write("decoy", {"v": float.hex(rate)})
        return rate

    evidence.decoy_chance_supports = alignment.decoy_chance_supports = decoys
    for name in ("fusion", "fusion.multi", "fusion.cache", "fusion.split", "fusion.confirmation",
                 "runtime.fusion_report", "fusion_sim"):
        try:
            importlib.import_module(name)
        except ImportError:                      # an older tree without the module
            pass
    for name, kind in (("align", "align"), ("align_at", "align_at")):
        original = getattr(alignment, name)
        wrapper = recorded(original, kind)
        for module in list(sys.modules.values()):
            if module is not None and module is not alignment and module.__dict__.get(name) is original:
                setattr(module, name, wrapper)
    script = root / "benchmarks" / "eval_fusion.py"
    sys.argv = [str(script), *eval_args]
    try:
        runpy.run_path(str(script), run_name="__main__")
    finally:
        log.close()


def _float(v):
    return float.fromhex(v) if isinstance(v, str) and v.lstrip("-").startswith("0x") else v


def differences(old: list[dict], new: list[dict], tolerance: float = 1e-9) -> list[str]:
    """What differs between two recordings, one line per field (empty: the same decisions)."""
    out = [] if len(old) == len(new) else [f"{len(old)} records against {len(new)}"]
    for n, (a, b) in enumerate(zip(old, new, strict=False)):
        if a == b:
            continue
        if a["k"] != b["k"] or a["k"] == "decoy":
            out.append(f"record {n}: {a} against {b}")
            continue
        for key in ("found", "reason", "supports"):
            if a[key] != b[key]:
                out.append(f"record {n} ({a['k']}): {key} {str(a[key])[:120]} against {str(b[key])[:120]}")
        for key in ("pose", "cov", "start"):
            x, y = a[key], b[key]
            if x == y:
                continue
            if x is None or y is None or len(x) != len(y) or any(
                    abs(_float(u) - _float(v)) > tolerance * max(1.0, abs(_float(u)))
                    for u, v in zip(x, y, strict=True)):
                out.append(f"record {n} ({a['k']}): {key} {x} against {y}")
        for key, x in a["stats"].items():
            y = b["stats"].get(key)
            if x == y:
                continue
            fx, fy = _float(x), _float(y)
            if isinstance(fx, float) and isinstance(fy, float) and (
                    abs(fx - fy) <= tolerance * max(1.0, abs(fx)) or (np.isnan(fx) and np.isnan(fy))):
                continue
            out.append(f"record {n} ({a['k']}): statistic {key} {fx} against {fy}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="run ROOT's eval_fusion.py, recording every decision")
    rec.add_argument("root", type=Path, help="the tree whose fusion and eval_fusion.py run")
    rec.add_argument("out", type=Path, help="JSON-lines file written")
    rec.add_argument("eval_args", nargs=argparse.REMAINDER, help="-- then eval_fusion.py's options")
    cmp = sub.add_parser("compare", help="every difference between two recordings (exit 1 if any)")
    cmp.add_argument("old", type=Path)
    cmp.add_argument("new", type=Path)
    args = parser.parse_args()
    if args.command == "record":
        eval_args = args.eval_args[1:] if args.eval_args[:1] == ["--"] else args.eval_args
        record(args.root, args.out, eval_args)
        return
    old = [json.loads(line) for line in args.old.read_text().splitlines()]
    new = [json.loads(line) for line in args.new.read_text().splitlines()]
    found = differences(old, new)
    kinds = {k: sum(r["k"] == k for r in old) for k in sorted({r["k"] for r in old})}
    print(f"{len(old)} records ({kinds}): {len(found)} differences")
    for line in found[:50]:
        print("  " + line)
    sys.exit(1 if found else 0)


if __name__ == "__main__":
    main()
