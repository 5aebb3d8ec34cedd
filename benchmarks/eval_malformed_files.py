"""Malformed files and lost links against the real commands, as subprocesses; prints the table of
docs/reliability.md.

    .venv/bin/python benchmarks/eval_malformed_files.py                 # every category (a few minutes)
    .venv/bin/python benchmarks/eval_malformed_files.py --only maps calib --jobs 2 --keep /tmp/malformed

Each input is generated here (seeded), labelled bad (must be refused), good (must be accepted) or either
(a random mutation: a clean refusal and an acceptance are both right, since what passes validation is a valid
file), and given to the command that reads it, in its own process with its address space capped
(``--memory-cap``, so that a reader that trusts a size field fails with MemoryError rather than taking the
machine down). An outcome is:
  clean error      exit status 2 (1 for ``calib`` until the CLI maps BadFileError to 2; 1 for a lost link), one
                   line on stderr, no traceback;
  accepted         exit status 0 (or 1 for ``fuse``: "no overlap" is an answer about readable maps);
  traceback        "Traceback" on stderr, a signal, a hang past ``--timeout``, or anything else.
Peak memory is the largest ``ru_maxrss`` of the category's processes (``os.wait4``), and each command's
baseline (a good input) is printed beside it. For calibrations every accepted file is also converted to SVS and
read back: ``calib convert`` must never write what ``calib show`` rejects.
"""
from __future__ import annotations

import argparse
import gzip
import io
import json
import math
import os
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections import defaultdict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.videre import calibration as cal  # noqa: E402
from mocks.stereo_head import default_calibration, default_calibration_text  # noqa: E402
from mocks.world import DEFAULT_WORLD_PATH  # noqa: E402
from runtime.commands.options import non_negative_int, positive_float, positive_int  # noqa: E402

PYTHON = sys.executable


@dataclass
class Case:
    category: str
    name: str
    argv: list[str]
    expect: str  # "bad" | "good" | "either"
    accept_status: tuple[int, ...] = (0,)
    error_status: tuple[int, ...] = (2,)
    follow_up: Callable[[], list[list[str]]] | None = None  # more commands to run if accepted (calib convert)


@dataclass
class Outcome:
    case: Case
    status: int | None
    stderr: str
    peak_mb: float
    seconds: float
    kind: str = ""
    note: str = ""


@dataclass
class Row:
    what: str
    outcomes: list[Outcome] = field(default_factory=list)


# ============================================================================ running
def run(argv: list[str], timeout: float, memory_cap: int, cwd: Path) -> tuple[int | None, str, float, float]:
    """(exit status or None for a signal/hang, stderr, peak RSS in MB, seconds)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory_cap, memory_cap))

    with tempfile.TemporaryFile() as err, tempfile.TemporaryFile() as out:
        start = time.monotonic()
        proc = subprocess.Popen([PYTHON, "-m", "runtime.cli", *argv], cwd=ROOT, stdout=out, stderr=err,
                                preexec_fn=limit, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        timer = threading.Timer(timeout, lambda: proc.send_signal(signal.SIGKILL))
        timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            timer.cancel()
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
        seconds = time.monotonic() - start
        err.seek(0)
        text = err.read().decode(errors="replace")
    code = proc.returncode if proc.returncode >= 0 else None
    return code, text, usage.ru_maxrss / 1024.0, seconds


def classify(case: Case, status: int | None, stderr: str) -> tuple[str, str]:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    if status is None or "Traceback" in stderr:
        return "traceback", (stderr.strip().splitlines() or ["killed"])[-1][:160]
    if status in case.accept_status:
        return ("wrongly accepted" if case.expect == "bad" else "accepted"), ""
    if status in case.error_status:
        if len(lines) != 1:
            return "messy error", f"{len(lines)} stderr lines: " + " | ".join(lines)[:160]
        return ("wrongly refused" if case.expect == "good" else "clean error"), lines[0][:200]
    return "other", f"status {status}: " + " | ".join(lines)[:160]


# ============================================================================ inputs
def _json_bytes(obj) -> np.ndarray:
    return np.frombuffer(json.dumps(obj).encode(), np.uint8)


def _map_arrays(n: int, seed: int, d: int = 64) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    desc = rng.normal(size=(n, d)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    meta = {"robot": f"r{seed}", "frame": "map", "robots": [f"r{seed}"], "metadata": {"true_start_pose": [0, 0, 0]}}
    return {"format": _json_bytes({"format": "p3at-landmark-map", "version": 1}),
            "positions": rng.uniform(-10, 10, (n, 3)), "covariances": np.tile(np.eye(3) * 0.01, (n, 1, 1)),
            "descriptors": desc, "ids": np.arange(n, dtype=np.int64), "counts": np.ones(n, np.int64),
            "seen_by": np.ones((n, 1), bool), "trajectory": rng.normal(size=(10, 4)), "meta": _json_bytes(meta)}


def _savez(path: Path, arrays: dict, compressed: bool = True) -> Path:
    (np.savez_compressed if compressed else np.savez)(path, **{k: v for k, v in arrays.items() if v is not None})
    return path


def _npy(header: dict, data: bytes) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, header)
    return out.getvalue() + data


def map_cases(folder: Path, rng: np.random.Generator) -> tuple[str, list[Case]]:
    base = _savez(folder / "base.npz", _map_arrays(300, 0))
    cases: list[Case] = []

    def fuse(name: str, path: Path, expect: str) -> None:
        cases.append(Case("maps", name, ["fuse", str(base), str(path), "--out", str(folder / f"out-{name}.npz")],
                          expect, accept_status=(0, 1)))

    good = _map_arrays(300, 0)
    meta = json.loads(good["meta"].tobytes())
    targeted: dict[str, dict] = {
        "strings as descriptors": {"descriptors": np.array([["a"] * 64] * 300)},
        "bytes as positions": {"positions": np.array([[b"x"] * 3] * 300)},
        "NaN positions": {"positions": np.full((300, 3), np.nan)},
        "infinite covariances": {"covariances": np.tile(np.where(np.eye(3) > 0, np.inf, 0), (300, 1, 1))},
        "huge covariances (1e200)": {"covariances": np.tile(np.eye(3) * 1e200, (300, 1, 1))},
        "negative-definite covariances": {"covariances": np.tile(-0.29 * np.eye(3), (300, 1, 1))},
        "zero covariances": {"covariances": np.zeros((300, 3, 3))},
        "asymmetric covariances": {"covariances": np.tile([[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], (300, 1, 1)) * 1.0},
        "indefinite covariances": {"covariances": np.tile([[1, 2, 0], [2, 1, 0], [0, 0, 1]], (300, 1, 1)) * 1.0},
        "positions 1e12 m": {"positions": np.full((300, 3), 1e12)},
        "meta.robots holds a number": {"meta": _json_bytes({**meta, "robots": [3]})},
        "meta.robot is a number": {"meta": _json_bytes({**meta, "robot": 7})},
        "meta.metadata is a list": {"meta": _json_bytes({**meta, "metadata": [1]})},
        "true_start_pose is a string": {"meta": _json_bytes({**meta, "metadata": {"true_start_pose": "abc"}})},
        "true_start_pose holds NaN": {"meta": np.frombuffer(
            json.dumps({**meta, "metadata": {"true_start_pose": [float("nan"), 0, 0]}}).encode(), np.uint8)},
        "meta is a list": {"meta": _json_bytes([1, 2])},
        "meta nested 100000 deep": {"meta": np.frombuffer(b'{"metadata": {"x": ' + b"[" * 100000 + b"]" * 100000
                                                          + b"}}", np.uint8)},
        "format version is a string": {"format": _json_bytes({"format": "p3at-landmark-map", "version": "1"})},
        "format version 99": {"format": _json_bytes({"format": "p3at-landmark-map", "version": 99})},
        "duplicate ids": {"ids": np.zeros(300, np.int64)},
        "ids past int64": {"ids": np.arange(300, dtype=np.uint64) + np.uint64(2**63)},
        "negative counts": {"counts": -np.ones(300, np.int64)},
        "seen_by as floats": {"seen_by": np.ones((300, 1))},
        "object array (pickle)": {"ids": np.array([object()] * 300, dtype=object)},
        "descriptors missing": {"descriptors": None},
        "covariances of the wrong shape": {"covariances": np.zeros((299, 3, 3))},
    }
    for name, change in targeted.items():
        arrays = {**good, **change}
        fuse(name, _savez(folder / f"{len(cases)}.npz", arrays, compressed="object" not in name), "bad")
    # headers and archives that lie
    with zipfile.ZipFile(folder / "trillion.npz", "w") as z:
        z.writestr("positions.npy", _npy({"descr": "<f8", "fortran_order": False, "shape": (10**12, 3)}, bytes(48)))
    fuse("header claiming 10^12 landmarks", folder / "trillion.npz", "bad")
    with zipfile.ZipFile(folder / "lie.npz", "w") as z:
        z.writestr("positions.npy", _npy({"descr": "<f8", "fortran_order": False, "shape": (10**6, 3)}, bytes(48)))
    fuse("header larger than its data", folder / "lie.npz", "bad")
    with zipfile.ZipFile(folder / "bomb.npz", "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("positions.npy", "w", force_zip64=True) as f:
            np.lib.format.write_array(f, np.zeros((120_000_000, 3)))  # 2.9 GB of zeros
    fuse(f"zip bomb ({(folder / 'bomb.npz').stat().st_size / 1e6:.1f} MB -> 2.9 GB)", folder / "bomb.npz", "bad")
    with zipfile.ZipFile(folder / "evil.npz", "w") as z:
        z.writestr("evil.pkl", b"cos\nsystem\n(S'true'\ntR.")
    fuse("unknown member (a pickle)", folder / "evil.npz", "bad")
    with zipfile.ZipFile(folder / "many.npz", "w") as z:
        for i in range(5000):
            z.writestr(f"m{i}.npy", b"")
    fuse("5000 members", folder / "many.npz", "bad")
    (folder / "text.npz").write_text("hello")
    fuse("not a zip", folder / "text.npz", "bad")
    (folder / "empty.npz").write_bytes(b"")
    fuse("empty file", folder / "empty.npz", "bad")
    fuse("missing file", folder / "absent.npz", "bad")
    # random damage
    raw = (folder / "base.npz").read_bytes()
    for k in range(40):
        data = bytearray(raw)
        for _ in range(int(rng.integers(1, 6))):
            data[int(rng.integers(0, len(data)))] = int(rng.integers(0, 256))
        (folder / f"flip{k}.npz").write_bytes(bytes(data))
        fuse(f"flip{k}", folder / f"flip{k}.npz", "either")
    for k in range(20):
        (folder / f"cut{k}.npz").write_bytes(raw[: int(rng.integers(0, len(raw)))])
        fuse(f"cut{k}", folder / f"cut{k}.npz", "either")
    for k in range(8):
        fuse(f"good{k}", _savez(folder / f"good{k}.npz", _map_arrays(int(rng.integers(20, 2000)), 100 + k),
                                compressed=bool(k % 2)), "good")
    return "map files (`p3at fuse`)", cases


def _random_calibration(seed: int) -> cal.StereoCalibration:
    import cv2
    r = np.random.default_rng(seed)
    f = r.uniform(400, 900)
    K1 = np.array([[f, 0, r.uniform(300, 340)], [0, f * r.uniform(0.98, 1.02), r.uniform(220, 260)], [0, 0, 1]])
    K2 = K1 + np.diag([r.uniform(-3, 3), r.uniform(-3, 3), 0])
    R, _ = cv2.Rodrigues(r.normal(0, 0.01, 3))
    T = np.array([-r.uniform(0.05, 0.2), r.normal(0, 0.002), r.normal(0, 0.002)])
    pose = np.concatenate([r.uniform(-0.5, 0.5, 3), r.normal(0, 0.05, 3)])
    return cal.from_intrinsics((640, 480), K1, r.normal(0, 0.02, 5), K2, r.normal(0, 0.02, 5), R, T, pose)


def calib_cases(folder: Path, rng: np.random.Generator) -> tuple[str, list[Case]]:
    import re
    cases: list[Case] = []
    cal.save(default_calibration(), folder / "good.yaml")
    cal.save(default_calibration(), folder / "good.xml")
    texts = {".yaml": (folder / "good.yaml").read_text(), ".xml": (folder / "good.xml").read_text(),
             ".ini": default_calibration_text()}

    def show(name: str, path: Path, expect: str) -> None:
        out = folder / f"conv-{path.stem}.ini"

        def convert_then_show() -> list[list[str]]:
            return [["calib", "convert", str(path), str(out)], ["calib", "show", str(out)]]
        cases.append(Case("calib", name, ["calib", "show", str(path)], expect, error_status=(1, 2),
                          follow_up=convert_then_show))

    def write(name: str, suffix: str, text: str, expect: str = "bad") -> None:
        path = folder / f"c{len(cases)}{suffix}"
        path.write_bytes(text.encode("latin-1", errors="replace"))
        show(name, path, expect)

    def yaml_matrix(name: str, data: str, rows: int = 3, cols: int = 3) -> str:
        pattern = re.compile(rf"({name}: !!opencv-matrix\n\s+rows: )\d+(\n\s+cols: )\d+"
                             rf"(\n\s+dt: d\n\s+data: )\[[^\]]*\]")
        return pattern.sub(lambda m: f"{m.group(1)}{rows}{m.group(2)}{cols}{m.group(3)}[ {data} ]", texts[".yaml"])

    y = texts[".yaml"]
    write("YAML width -640", ".yaml", y.replace("image_width: 640", "image_width: -640"))
    write("YAML width 1e11", ".yaml", y.replace("image_width: 640", "image_width: 100000000000"))
    write("YAML width a string", ".yaml", y.replace("image_width: 640", 'image_width: "wide"'))
    write("YAML width 640.5", ".yaml", y.replace("image_width: 640", "image_width: 640.5"))
    write("YAML M1 claims 100000x100000", ".yaml", yaml_matrix("M1", "0.", 100000, 100000))
    write("YAML M1 holds strings", ".yaml", yaml_matrix("M1", '"a", b, 319.5, 0., 520., 239.5, 0., 0., 1.'))
    write("YAML negative focal length", ".yaml", yaml_matrix("M1", "-520., 0., 319.5, 0., 520., 239.5, 0., 0., 1."))
    write("YAML principal point far outside", ".yaml",
          yaml_matrix("M1", "520., 0., 3190.5, 0., 520., 239.5, 0., 0., 1."))
    write("YAML all-zero R1", ".yaml", yaml_matrix("R1", ", ".join(["0."] * 9)))
    write("YAML R a reflection", ".yaml", yaml_matrix("R", "1., 0., 0., 0., 1., 0., 0., 0., -1."))
    write("YAML negative baseline", ".yaml",
          yaml_matrix("P2", "520., 0., 319.5, 46.8, 0., 520., 239.5, 0., 0., 0., 1., 0.", 3, 4))
    write("YAML NaN in P2", ".yaml",
          yaml_matrix("P2", "520., 0., 319.5, .nan, 0., 520., 239.5, 0., 0., 0., 1., 0.", 3, 4))
    write("YAML distortion 1e9", ".yaml", yaml_matrix("D1", "1e9, 0., 0., 0., 0.", 1, 5))
    write("YAML 2 MB of comments", ".yaml", y + "#" * (2 << 20))
    write("YAML top level is a list", ".yaml", "%YAML:1.0\n---\n- 1\n- 2\n")
    xml = texts[".xml"]
    write("XML width -640", ".xml", xml.replace("<image_width>640", "<image_width>-640"))
    write("XML width a word", ".xml", xml.replace("<image_width>640", "<image_width>wide"))
    write("XML M1 claims 100000 rows", ".xml", xml.replace("<rows>3</rows>", "<rows>100000</rows>", 1))
    write("XML not closed", ".xml", xml[: len(xml) // 2])
    ini = texts[".ini"]

    def svs(section: str, key: str, value: str) -> str:
        head, rest = ini.split(f"[{section}]", 1)
        return f"{head}[{section}]" + re.sub(rf"(?m)^{key} .*$", f"{key} {value} ", rest, count=1)
    write("SVS width -640", ".ini", svs("left camera", "pwidth", "-640"))
    write("SVS width 1e11", ".ini", svs("left camera", "pwidth", "1e11"))
    write("SVS width a word", ".ini", svs("left camera", "pwidth", "wide"))
    write("SVS focal 0", ".ini", svs("left camera", "f", "0"))
    write("SVS Tx 0", ".ini", svs("external", "Tx", "0"))
    write("SVS head 1e9 mm away", ".ini", svs("global", "GTx", "1e9"))
    head, rest = ini.split("[left camera]", 1)
    lines = rest.split("\n")
    at = lines.index("rect")
    lines[at + 1: at + 4] = ["  0 0 0 "] * 3
    write("SVS all-zero rect", ".ini", f"{head}[left camera]" + "\n".join(lines))
    write("SVS not an SVS file", ".ini", "hello\n")
    for suffix, count in ((".yaml", 20), (".xml", 10), (".ini", 20)):
        raw = bytearray(texts[suffix].encode("latin-1"))
        for k in range(count):
            data = bytearray(raw)
            at = int(rng.integers(0, len(data) - 8))
            junk = rng.choice(list(b"0123456789.-eE x[]:,\n<>/"), size=int(rng.integers(1, 8))).astype(np.uint8)
            data[at: at + len(junk)] = bytes(junk)
            write(f"flip{suffix}{k}", suffix, data.decode("latin-1"), "either")
    for k in range(4):
        for suffix in (".yaml", ".xml", ".ini"):
            path = folder / f"good{k}{suffix}"
            cal.save(_random_calibration(k), path)
            show(f"good{k}{suffix}", path, "good")
    return "calibration files (`p3at calib show`, then `convert` + `show`)", cases


def _flaser(i: int, n: int = 181, rng: np.random.Generator | None = None) -> str:
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = np.minimum(4.0 / np.maximum(np.abs(np.cos(angles)), 1e-3), 8.0) - 0.02 * i
    if rng is not None:
        ranges = ranges + rng.normal(0, 0.005, n)
    return f"FLASER {n} " + " ".join(f"{r:.3f}" for r in ranges) + f" {0.02 * i:.3f} 0 0 0 0 0 {i} host {i}"


def carmen_cases(folder: Path, rng: np.random.Generator) -> tuple[str, list[Case]]:
    cases: list[Case] = []
    body = "\n".join(["# synthetic", "PARAM robot x"] + [_flaser(i, rng=rng) for i in range(40)]) + "\n"
    gz = gzip.compress(body.encode(), mtime=0)

    def scan(name: str, path: Path, expect: str, *extra: str) -> None:
        cases.append(Case("carmen", name, ["scanmatch", str(path), "--matcher", "icp", *extra], expect,
                          accept_status=(0,), error_status=(2,)))

    def write(name: str, data: bytes, suffix: str, expect: str = "bad", *extra: str) -> None:
        path = folder / f"l{len(cases)}{suffix}"
        path.write_bytes(data)
        scan(name, path, expect, *extra)

    for fraction in (0.1, 0.3, 0.5, 0.7, 0.9, 0.99):
        write(f".gz cut at {fraction:.0%}", gz[: int(len(gz) * fraction)], ".log.gz")
    write(".gz cut at 50 %, --allow-truncated", gz[: len(gz) // 2], ".log.gz", "good", "--allow-truncated")
    for k in range(5):
        data = bytearray(gz)
        at = int(len(data) * (0.2 + 0.15 * k))
        data[at: at + 40] = rng.integers(0, 256, 40).astype(np.uint8).tobytes()
        write(f".gz corrupted at {0.2 + 0.15 * k:.0%}", bytes(data), ".log.gz")
    lines = body.splitlines()
    for name, bad in (("NaN range", _flaser(0).replace(" 4.000", " nan", 1)),
                      ("negative range", _flaser(0).replace(" 4.000", " -4.000", 1)),
                      ("count 10^9", "FLASER 1000000000 1 2 3"), ("count not a number", "FLASER many 1 2"),
                      ("missing fields", "FLASER 181 1 2 3"), ("pose not a number", _flaser(0).replace(
                          " 0.000 0 0 0", " x 0 0 0", 1))):
        write(f"line 20: {name}", ("\n".join(lines[:20] + [bad] + lines[20:]) + "\n").encode(), ".log")
    write("2 MB without a newline", b"FLASER " + b"1 " * (1 << 20), ".log")
    write("binary junk", rng.integers(0, 256, 5000).astype(np.uint8).tobytes(), ".log")
    write("not gzip", b"hello", ".log.gz")
    write("empty", b"", ".log")
    scan("missing file", folder / "absent.log", "bad")
    for k in range(20):
        data = bytearray(gz)
        for _ in range(int(rng.integers(1, 4))):
            data[int(rng.integers(0, len(data)))] = int(rng.integers(0, 256))
        write(f"flip{k}", bytes(data), ".log.gz", "either")
    for k in range(3):
        write(f"good{k}", gzip.compress(body.encode()) if k else body.encode(), ".log.gz" if k else ".log", "good")
    for value in ("nan", "inf", "-1", "0", "x"):
        scan(f"--max-distance {value}", folder / "l0.log.gz", "bad", "--max-distance", value)
    for option, value in (("--step", "0"), ("--limit", "1"), ("--step", "1.5")):
        scan(f"{option} {value}", folder / "l0.log.gz", "bad", option, value)
    return "CARMEN logs and arguments (`p3at scanmatch`)", cases


def world_cases(folder: Path, rng: np.random.Generator) -> tuple[str, list[Case]]:
    cases: list[Case] = []
    doc = json.loads(DEFAULT_WORLD_PATH.read_text())

    def serve(name: str, text: str | bytes, expect: str) -> None:
        path = folder / f"w{len(cases)}.json"
        path.write_bytes(text.encode() if isinstance(text, str) else text)
        cases.append(Case("world", name, ["robot", "serve", "--tcp", "0", "--world", str(path), "--duration", "0"],
                          expect))

    serve("nested 100000 deep", "[" * 100_000 + "]" * 100_000, "bad")
    serve("a 5000-digit integer", '{"version": 1, "feature_seed": ' + "9" * 5000 + "}", "bad")
    serve("a wall to 1e300", json.dumps({**doc, "walls": [{"from": [0, 0], "to": [1e300, 0]}]}), "bad")
    serve("10001 walls", json.dumps({**doc, "walls": [{"from": [0, 0], "to": [1, 0]}] * 10_001}), "bad")
    serve("feature_seed 2^70", json.dumps({**doc, "feature_seed": 2**70}), "bad")
    serve("wall height 1e9", json.dumps({**doc, "default_wall_height": 1e9}), "bad")
    serve("misspelt key", json.dumps({**doc, "wals": []}), "bad")
    serve("walls missing", json.dumps({k: v for k, v in doc.items() if k != "walls"}), "bad")
    serve("not JSON", "{walls", "bad")
    serve("not UTF-8", b"\xff\xfe\x00", "bad")
    junk = [None, True, -1, 1e308, float("nan"), "x", [], {}, [1, 2, 3]]

    def mutate(value):
        if isinstance(value, dict) and value and rng.random() < 0.7:
            key = sorted(value)[int(rng.integers(0, len(value)))]
            return {**value, key: mutate(value[key])}
        if isinstance(value, list) and value and rng.random() < 0.7:
            i = int(rng.integers(0, len(value)))
            return value[:i] + [mutate(value[i])] + value[i + 1:]
        return junk[int(rng.integers(0, len(junk)))]
    for k in range(20):
        serve(f"mutation{k}", json.dumps(mutate(doc)), "either")
    serve("the packaged building", DEFAULT_WORLD_PATH.read_text(), "good")
    serve("a box", json.dumps({"version": 1, "name": "box", "walls": [
        {"from": [0, 0], "to": [5, 0]}, {"from": [5, 0], "to": [5, 5]}, {"from": [5, 5], "to": [0, 5]},
        {"from": [0, 5], "to": [0, 0]}], "start_poses": {"robot1": [2, 2, 0]}}), "good")
    return "world files (`p3at robot serve --world`)", cases


def route_cases(folder: Path, rng: np.random.Generator) -> tuple[str, list[Case]]:
    cases: list[Case] = []

    def simulate(name: str, text: str | bytes, expect: str) -> None:
        path = folder / f"r{len(cases)}.route"
        path.write_bytes(text.encode() if isinstance(text, str) else text)
        cases.append(Case("route", name, ["slam", "simulate", "--world-route", str(path), "--seconds", "0.5",
                                          "--particles", "3", "--out", str(folder / f"r{len(cases)}.npz")], expect))

    for name, text in (("NaN", "1 2\n3 nan\n"), ("1e300", "1 2\n1e300 0\n"), ("three numbers", "1 2 3\n"),
                       ("only a comment", "# nothing\n"), ("100001 waypoints", "0 0\n" * 100_001),
                       ("a word", "one two\n"), ("not UTF-8", b"\xff\xfe1 2\n"), ("empty", "")):
        simulate(name, text, "bad")
    for k in range(12):
        raw = rng.choice(list(b"0123456789.-e, #\nnaifNAIF"), size=int(rng.integers(0, 120))).astype(np.uint8)
        simulate(f"random{k}", raw.tobytes(), "either")
    simulate("a corridor", "-9 4\n-3 4\n", "good")
    simulate("with comments and commas", "# start\n-9, 4\n-6, 4  # half way\n-3, 4\n", "good")
    return "route files (`p3at slam simulate --world-route`)", cases


def drive_argument_cases(folder: Path, rng: np.random.Generator) -> tuple[str, list[Case]]:
    cases = [Case("drive-args", " ".join(a), ["robot", "drive", "socket://127.0.0.1:1", "--seconds", "1", *a], "bad")
             for a in (["--vel", "nan"], ["--rvel", "inf"], ["--seconds", "nan"], ["--every", "0"],
                       ["--link-timeout", "-1"])]
    return "nonsense numbers (`p3at robot drive`)", cases


CATEGORIES = {"maps": map_cases, "calib": calib_cases, "carmen": carmen_cases, "world": world_cases,
              "route": route_cases, "drive-args": drive_argument_cases}


# ============================================================================ lost link
class SilentProxy:
    """A TCP relay to a server that can go silent (stop forwarding, keep both sockets open): the link dies the
    way a serial cable pulled from a bridge does, with no FIN to notice."""

    def __init__(self, target_port: int) -> None:
        import socket
        self.silent = threading.Event()
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self._listener.getsockname()[1]}"
        self._target = target_port
        self._sockets: list = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        import socket
        client, _ = self._listener.accept()
        server = socket.create_connection(("127.0.0.1", self._target))
        self._sockets += [client, server]
        for a, b in ((client, server), (server, client)):
            threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, src, dst) -> None:
        try:
            while data := src.recv(4096):
                if not self.silent.is_set():
                    dst.sendall(data)
        except OSError:
            pass

    def close(self) -> None:
        for sock in [*self._sockets, self._listener]:
            sock.close()


def lost_link_trials(n: int, memory_cap: int) -> tuple[Row, dict[str, list[float]]]:
    """``p3at robot drive`` against a virtual robot whose link is lost mid-drive, three ways in turn: the TCP
    server closes, the pty server closes, the TCP link goes silent (relay stops forwarding)."""
    from mocks.p3at import serve_pty, serve_tcp
    from mocks.world import World

    row = Row("lost link mid-drive (`p3at robot drive`: TCP server closed, pty closed, TCP link silent)")
    delays: dict[str, list[float]] = defaultdict(list)
    world = World.load()
    pose = world.start_poses["robot1"]
    for k in range(n):
        how = ("tcp closed", "pty closed", "tcp silent")[k % 3]
        server = serve_pty(world, f"robot{k}", pose) if how == "pty closed" else serve_tcp(world, f"robot{k}", pose,
                                                                                          port=0)
        proxy = SilentProxy(server.port) if how == "tcp silent" else None
        url = proxy.url if proxy else server.url
        proc = subprocess.Popen([PYTHON, "-m", "runtime.cli", "robot", "drive", url, "--vel", "0.2",
                                 "--seconds", "600", "--every", "0.1"], cwd=ROOT, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
                                preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (memory_cap, memory_cap)))
        proc.stdout.readline()
        proc.stdout.readline()  # header and one state: driving
        lost = time.monotonic()
        if proxy:
            proxy.silent.set()
        else:
            server.close()
        timer = threading.Timer(60, lambda p=proc: p.send_signal(signal.SIGKILL))
        timer.start()
        _, status, usage = os.wait4(proc.pid, 0)
        timer.cancel()
        delays[how].append(time.monotonic() - lost)
        if proxy:
            proxy.close()
        server.close()
        proc.returncode = os.waitstatus_to_exitcode(status)
        err = proc.stderr.read()
        case = Case("lost-link", f"{how} {k}", [], "bad", error_status=(1,))
        kind, note = classify(case, proc.returncode if proc.returncode >= 0 else None, err)
        if kind == "clean error" and "link lost" not in err:
            kind, note = "other", err.strip()[:160]
        row.outcomes.append(Outcome(case, proc.returncode, err, usage.ru_maxrss / 1024.0, delays[how][-1], kind,
                                    note))
    return row, delays


# ============================================================================ main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=[*CATEGORIES, "lost-link"], help="categories to run")
    parser.add_argument("--jobs", type=positive_int, default=2, help="processes at a time (default 2)")
    parser.add_argument("--timeout", type=positive_float, default=120.0, help="seconds before a process counts as hung")
    parser.add_argument("--memory-cap", type=positive_float, default=4.0, help="address-space cap per process, GiB")
    parser.add_argument("--trials", type=positive_int, default=12, help="lost-link trials (a third of each kind)")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--keep", type=Path, help="write the inputs here and keep them")
    parser.add_argument("--verbose", action="store_true", help="print every outcome")
    args = parser.parse_args()
    cap = int(args.memory_cap * (1 << 30))
    folder = args.keep or Path(tempfile.mkdtemp(prefix="malformed-"))
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    rows: list[Row] = []
    chosen = args.only or [*CATEGORIES, "lost-link"]
    started = time.monotonic()
    try:
        for name in chosen:
            if name == "lost-link":
                row, delays = lost_link_trials(args.trials, cap)
                rows.append(row)
                for how, values in delays.items():
                    print(f"# lost link ({how}): the command exited {statistics.median(values):.2f} s after the loss "
                          f"(median of {len(values)}), at most {max(values):.2f} s", flush=True)
                continue
            sub = folder / name
            sub.mkdir(exist_ok=True)
            what, cases = CATEGORIES[name](sub, rng)
            row = Row(what)

            def one(case: Case) -> Outcome:
                status, stderr, peak, seconds = run(case.argv, args.timeout, cap, ROOT)
                kind, note = classify(case, status, stderr)
                if kind == "accepted" and case.follow_up is not None:
                    for argv in case.follow_up():
                        s2, e2, p2, _ = run(argv, args.timeout, cap, ROOT)
                        peak = max(peak, p2)
                        if s2 != 0:
                            kind, note = "convert wrote what show rejects", f"{argv[:2]}: {e2.strip()[:160]}"
                            break
                return Outcome(case, status, stderr, peak, seconds, kind, note)
            with ThreadPoolExecutor(args.jobs) as pool:
                row.outcomes = list(pool.map(one, cases))
            rows.append(row)
            print(f"# {what}: {len(cases)} inputs in {time.monotonic() - started:.0f} s", flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    print_table(rows, args.verbose)


def print_table(rows: list[Row], verbose: bool) -> None:
    print()
    print("| what was tried | inputs | clean errors | accepted rightly | wrongly accepted / refused | tracebacks "
          "(or hangs, other) | peak memory (good input) |")
    print("|---|---|---|---|---|---|---|")
    totals: dict[str, int] = defaultdict(int)
    for row in rows:
        kinds = defaultdict(int)
        for o in row.outcomes:
            kinds[o.kind] += 1
            totals[o.kind] += 1
        peak = max(o.peak_mb for o in row.outcomes)
        good = [o.peak_mb for o in row.outcomes if o.case.expect == "good"]
        base = f" ({max(good):.0f} MB)" if good else ""
        wrong = kinds["wrongly accepted"] + kinds["wrongly refused"] + kinds["convert wrote what show rejects"]
        bad = kinds["traceback"] + kinds["other"] + kinds["messy error"]
        print(f"| {row.what} | {len(row.outcomes)} | {kinds['clean error']} | {kinds['accepted']} | {wrong} | "
              f"{bad} | {peak:.0f} MB{base} |")
    print(f"\ntotal: {sum(totals.values())} inputs; " + ", ".join(f"{k}: {v}" for k, v in sorted(totals.items())))
    for row in rows:
        for o in row.outcomes:
            if verbose or o.kind not in ("clean error", "accepted"):
                print(f"  [{o.kind}] {o.case.category}/{o.case.name} (status {o.status}, {o.peak_mb:.0f} MB, "
                      f"{o.seconds:.1f} s): {o.note}")


if __name__ == "__main__":
    main()
