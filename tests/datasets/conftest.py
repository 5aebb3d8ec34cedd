"""Fixtures for the dataset tests: a small synthetic MRCLAM folder with exact measurements, and the real one."""
from __future__ import annotations

import contextlib
import gzip
import io
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
MRCLAM2 = DATA / "mrclam" / "MRCLAM_Dataset2"

LANDMARKS = {6: (2.0, 0.0), 7: (0.0, 2.5), 8: (-2.0, 0.5), 9: (0.5, -2.5), 10: (3.0, 3.0)}
BARCODES = {1: 5, 2: 14, 3: 41, 6: 18, 7: 45, 8: 7, 9: 63, 10: 16}   # subject -> barcode
SENSOR_RANGE, SENSOR_FOV = 4.5, np.radians(120.0)  # the synthetic camera reports every landmark in this footprint


def run_cli(*argv) -> tuple[int, str, str]:
    """``p3at ARGV...`` in this process: (exit status, stdout, stderr)."""
    from runtime.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(list(argv))
    return status, out.getvalue(), err.getvalue()


def gauss_markov(rng: np.random.Generator, n: int, sigma: float, decay: float) -> np.ndarray:
    """(n,) a stationary first-order Gauss–Markov series: stationary deviation ``sigma``, ``decay`` = e^(−Δt/τ) per
    step (a drifting heading bias per metre, session 22)."""
    series = np.empty(n)
    series[0] = sigma * rng.standard_normal()
    shocks = sigma * np.sqrt(1 - decay ** 2) * rng.standard_normal(n)
    for k in range(1, n):
        series[k] = decay * series[k - 1] + shocks[k]
    return series


def _write(path: Path, header: str, rows, gz: bool) -> None:
    text = header + "".join(" ".join(f"{v:.10g}" for v in row) + "\n" for row in rows)
    if gz:
        with gzip.open(path.with_name(path.name + ".gz"), "wt") as stream:
            stream.write(text)
    else:
        path.write_text(text)


def write_mrclam(folder: Path, *, robot: int = 1, gz: bool = True, swap: tuple[int, int] | None = None,
                 seconds: float = 60.0) -> dict:
    """A synthetic MRCLAM folder: robot ``robot`` drives a circle (0.2 m/s, 0.1 rad/s) among LANDMARKS and sees
    every landmark in its footprint (SENSOR_RANGE, SENSOR_FOV) every 0.2 s (exact), plus robot 2 now and then.
    ``swap``: two subjects whose barcodes Barcodes.dat exchanges. Returns the truth (start pose, trajectory)."""
    folder.mkdir(parents=True, exist_ok=True)
    t = np.round(np.arange(0.0, seconds, 0.02), 2)
    v, w = 0.2, 0.1
    start = np.array([0.3, -0.4, 0.2])
    theta = start[2] + w * t
    x = start[0] + v / w * (np.sin(theta) - np.sin(start[2]))
    y = start[1] - v / w * (np.cos(theta) - np.cos(start[2]))
    _write(folder / f"Robot{robot}_Odometry.dat", "# Time [s]    Forward Velocity [m/s]    Angular Velocity [rad/s]\n",
           [(ti, v, w) for ti in t], gz)
    _write(folder / f"Robot{robot}_Groundtruth.dat", "# Time [s]    x [m]    y [m]    orientation [rad]\n",
           np.column_stack([t, x, y, np.angle(np.exp(1j * theta))]), gz)
    ids = np.array(sorted(LANDMARKS))
    positions = np.array([LANDMARKS[i] for i in ids])
    rows = []
    for k in range(0, len(t), 10):
        d = positions - [x[k], y[k]]
        r = np.hypot(d[:, 0], d[:, 1])
        bearing = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - theta[k])))
        for j in np.flatnonzero((r < SENSOR_RANGE) & (np.abs(bearing) < SENSOR_FOV / 2)):
            rows.append((t[k], BARCODES[int(ids[j])], r[j], bearing[j]))
        if k % 200 == 0:
            rows.append((t[k], BARCODES[2], 1.0, 0.1))
    _write(folder / f"Robot{robot}_Measurement.dat", "# Time [s]    Subject #    range [m]    bearing [rad]\n", rows,
           gz)
    table = dict(BARCODES)
    if swap:
        table[swap[0]], table[swap[1]] = table[swap[1]], table[swap[0]]
    _write(folder / "Barcodes.dat", "# Subject #    Barcode #\n", sorted(table.items()), gz)
    _write(folder / "Landmark_Groundtruth.dat", "# Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]\n",
           [(i, *LANDMARKS[i], 0.001, 0.001) for i in ids], gz)
    return {"start": start, "truth": np.column_stack([t, x, y, theta]), "sightings": len(rows)}


@pytest.fixture
def mrclam_dir():
    if not (MRCLAM2 / "Robot1_Odometry.dat.gz").is_file() and not (MRCLAM2 / "Robot1_Odometry.dat").is_file():
        pytest.skip(f"MRCLAM data set 2 not found in {MRCLAM2.resolve()} (../shared/data/mrclam, see its README)")
    return MRCLAM2


@pytest.fixture(scope="session")
def synthetic():
    """The synthetic MRCLAM writer and its landmarks: ``synthetic.write(folder, ...)``, ``synthetic.LANDMARKS``."""
    return _Synthetic()


class _Synthetic:
    LANDMARKS = LANDMARKS
    SENSOR_RANGE, SENSOR_FOV = SENSOR_RANGE, SENSOR_FOV
    BARCODES = BARCODES
    write = staticmethod(write_mrclam)
