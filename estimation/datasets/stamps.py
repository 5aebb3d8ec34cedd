"""How finely a log's time stamps were written: a stream whose stamps sit on a grid coarser than its rows.

A data set written with a fixed number of significant digits loses a decimal of its stamps at every power of
ten: MRCLAM's copy here has five, so from t = 1000 s every file's stamps are multiples of 0.1 s, and five 50 Hz
odometry rows share one stamp (a sighting's time is then uncertain by ±0.05 s). :func:`stamp_quantization` finds
that from the stamps alone: each stamp's coarsest decimal grid (the largest 10^k it is a multiple of), the
coarsest grid every later stamp sits on (a suffix minimum, so it only grows along the log), and the first time
from which that grid holds. A grid change held by fewer than ``MIN_STAMPS`` distinct stamps is chance (a last
stamp 1900.0 is a multiple of 100) and belongs to the finer grid before it.

It is reported, never acted on: the reader's notes and ``RangeBearingLog.stamp_resolution`` carry it.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

MIN_STAMPS = 20                # distinct stamps a coarser grid must hold to be told apart from chance
COARSER = 1.5                  # a grid this many times the finer one (or the row interval) counts as coarser
_POWERS = np.arange(6, -10, -1)  # the grids tried, 1e6 s down to 1e-9 s


@dataclass(frozen=True)
class StampQuantization:
    """One stream's stamps sit on a grid of ``resolution_s`` from ``from_s`` on.

    stream: "odometry", "sightings", "ground truth"; rows / stamps: the rows from ``from_s`` on and their distinct
    stamps; earlier_resolution_s: the grid before ``from_s`` (None: the whole stream is on this grid);
    row_interval_s: the stream's mean row interval over the whole log (its duration over its rows).
    """

    stream: str
    resolution_s: float
    from_s: float
    rows: int
    stamps: int
    earlier_resolution_s: float | None
    row_interval_s: float

    @property
    def rows_per_stamp(self) -> float:
        return self.rows / max(self.stamps, 1)

    def as_dict(self) -> dict:
        return asdict(self) | {"rows_per_stamp": self.rows_per_stamp}

    def brief(self) -> str:
        before = "" if self.earlier_resolution_s is None else f"{_seconds(self.earlier_resolution_s)} before; "
        return (f"{self.stream} on a {_seconds(self.resolution_s)} grid from t = {self.from_s:g} s ({before}"
                f"{self.rows_per_stamp:.1f} rows a stamp)")


def _seconds(value: float) -> str:
    return f"{value:.3g} s"


def stamp_grids(times: np.ndarray) -> np.ndarray:
    """Each stamp's coarsest decimal grid (N,): the largest 10^k (1e-9 ≤ 10^k ≤ 1e6 s) it is a multiple of.

    A grid finer than the float's own precision at that stamp (100 ulps) does not count; 0 is on every grid (1e6).
    """
    t = np.asarray(times, np.float64).reshape(-1)
    tolerance = 1e-12 * np.maximum(1.0, np.abs(t))
    grid = np.zeros(len(t))
    for k in _POWERS:
        r = 10.0 ** float(k)
        on = (grid == 0) & (np.abs(t - np.round(t / r) * r) <= tolerance) & (r > 100.0 * tolerance)
        grid[on] = r
    # no grid at all (a stamp finer than 1e-9 s relative to its size): the finest grid tried
    grid[grid == 0] = 10.0 ** float(_POWERS[-1])
    return grid


def stamp_quantization(times, stream: str) -> StampQuantization | None:
    """The coarse grid ``times`` (non-decreasing, s) end on, if it is coarser than the grid before it or than the
    stream's rows (its mean interval); None otherwise (fewer than ``MIN_STAMPS`` distinct stamps: None)."""
    t = np.asarray(times, np.float64).reshape(-1)
    n = len(t)
    distinct = np.concatenate([[0], np.cumsum(np.diff(t) > 0)])     # distinct stamps before row i (minus one)
    if n == 0 or distinct[-1] + 1 < MIN_STAMPS:
        return None
    suffix = np.minimum.accumulate(stamp_grids(t)[::-1])[::-1]      # the grid every stamp from i on sits on
    # levels of the suffix minimum (it only grows); a level of fewer than MIN_STAMPS stamps is merged back
    starts = np.concatenate([[0], np.flatnonzero(np.diff(suffix) > 0) + 1])
    levels = []                                                    # (first row, grid)
    for first, end in zip(starts, np.concatenate([starts[1:], [n]]), strict=True):
        if levels and distinct[end - 1] - distinct[first] + 1 < MIN_STAMPS:
            continue
        if levels and suffix[first] <= COARSER * levels[-1][1]:
            continue
        levels.append((int(first), float(suffix[first])))
    first, resolution = levels[-1]
    earlier = levels[-2][1] if len(levels) > 1 else None
    interval = float(t[-1] - t[0]) / (n - 1)
    coarse = earlier is not None or resolution > COARSER * interval
    if not coarse:
        return None
    tail = t[first:]
    return StampQuantization(stream=stream, resolution_s=resolution, from_s=float(tail[0]), rows=len(tail),
                             stamps=len(np.unique(tail)), earlier_resolution_s=earlier, row_interval_s=interval)


def quantization_note(found: tuple[StampQuantization, ...]) -> str | None:
    """One sentence for a log's notes naming every quantized stream (None when there is none)."""
    if not found:
        return None
    widest = max(q.resolution_s for q in found)
    return ("time stamps written coarser than the rows (not corrected): " + ", ".join(q.brief() for q in found)
            + f"; a time on a {_seconds(widest)} grid is uncertain by ±{_seconds(widest / 2)}")


def spread_rows(times, quantization: StampQuantization) -> np.ndarray:
    """An opt-in for measurement (``read_mrclam(spread=...)``), not a default: the rows sharing a coarse stamp
    placed evenly about it at the stream's own row interval (at most the grid over the rows), earlier rows kept.

    k rows of stamp t become t + (i - (k - 1)/2) h, i = 0..k-1, h = min(row interval, grid / k); the result is
    non-decreasing when the rows were (no row is moved before the last row ahead of the coarse grid)."""
    t = np.asarray(times, np.float64).reshape(-1).copy()
    first = int(np.searchsorted(t, quantization.from_s, side="left"))
    tail = t[first:]
    stamps, start, counts = np.unique(tail, return_index=True, return_counts=True)
    rank = np.arange(len(tail)) - np.repeat(start, counts)
    k = np.repeat(counts, counts).astype(float)
    h = np.minimum(quantization.row_interval_s, quantization.resolution_s / k)
    spread = tail + (rank - (k - 1.0) / 2.0) * h
    # the first coarse stamp may hold only its later rows (999.98 is still written finely): not before the row ahead
    t[first:] = np.maximum(spread, t[first - 1]) if first > 0 else spread
    return t
