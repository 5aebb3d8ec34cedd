"""Tiny PNG plots with OpenCV (matplotlib is not installed): line plots and 2-D / 3-D landmark maps."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

WHITE = (255, 255, 255)
BLACK = (0, 0, 0)
GREY = (200, 200, 200)
# BGR
COLOURS = [(200, 90, 30), (30, 120, 230), (60, 170, 60), (40, 40, 200), (160, 60, 160), (0, 160, 200)]
FONT = cv2.FONT_HERSHEY_SIMPLEX


def _canvas(width: int, height: int) -> np.ndarray:
    return np.full((height, width, 3), 255, np.uint8)


def _text(img, text, org, scale=0.45, colour=BLACK, thickness=1):
    cv2.putText(img, text, (int(org[0]), int(org[1])), FONT, scale, colour, thickness, cv2.LINE_AA)


def _write(img: np.ndarray, path: str | Path) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"cannot encode {path}")
    Path(path).write_bytes(buf.tobytes())


def _legend(img: np.ndarray, groups, title: str) -> None:
    x = 20
    for label, p, colour in groups:
        cv2.circle(img, (x + 5, 40), 5, colour, -1)
        _text(img, f"{label} ({len(p)})", (x + 14, 45), 0.45)
        x += 14 + 9 * (len(label) + 6)
    _text(img, title, (20, 22), 0.55)


def line_plot(path, x, series: dict[str, np.ndarray], title: str, xlabel: str, ylabel: str,
              width: int = 760, height: int = 420, y_max: float | None = None, hlines: dict[str, float] | None = None):
    """series: label -> y values (len(x),), NaN = gap."""
    img = _canvas(width, height)
    left, right, top, bottom = 70, 20, 40, 60
    pw, ph = width - left - right, height - top - bottom
    x = np.asarray(x, float)
    ys = np.concatenate([np.asarray(v, float) for v in series.values()])
    y_hi = y_max if y_max is not None else float(np.nanmax(ys)) * 1.1 if np.isfinite(np.nanmax(ys)) else 1.0
    y_hi = max(y_hi, 1e-9)
    x_lo, x_hi = float(x.min()), float(x.max()) if x.max() > x.min() else float(x.min()) + 1

    def px(xv, yv):
        return (left + (xv - x_lo) / (x_hi - x_lo) * pw, top + ph - min(yv, y_hi) / y_hi * ph)

    cv2.rectangle(img, (left, top), (left + pw, top + ph), BLACK, 1)
    for t in np.linspace(0, y_hi, 6):
        p = px(x_lo, t)
        cv2.line(img, (left, int(p[1])), (left + pw, int(p[1])), GREY, 1)
        _text(img, f"{t:.3g}", (5, p[1] + 4), 0.4)
    for t in x:
        p = px(t, 0)
        _text(img, f"{t:.2g}", (p[0] - 10, top + ph + 18), 0.4)
    for label, value in (hlines or {}).items():
        p = px(x_lo, value)
        cv2.line(img, (left, int(p[1])), (left + pw, int(p[1])), (120, 120, 120), 1, cv2.LINE_AA)
        _text(img, label, (left + 5, p[1] - 4), 0.4, (120, 120, 120))
    for k, (label, y) in enumerate(series.items()):
        colour = COLOURS[k % len(COLOURS)]
        y = np.asarray(y, float)
        pts = [px(a, b) for a, b in zip(x, y, strict=True)]
        for a, b, ya, yb in zip(pts[:-1], pts[1:], y[:-1], y[1:], strict=True):
            if np.isfinite(ya) and np.isfinite(yb):
                cv2.line(img, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), colour, 2, cv2.LINE_AA)
        for p, yv in zip(pts, y, strict=True):
            if np.isfinite(yv):
                cv2.circle(img, (int(p[0]), int(p[1])), 3, colour, -1, cv2.LINE_AA)
        _text(img, label, (left + pw - 230, top + 18 + 18 * k), 0.45, colour)
    _text(img, title, (left, 25), 0.55)
    _text(img, xlabel, (left + pw / 2 - 60, height - 15), 0.45)
    _text(img, ylabel, (5, top - 8), 0.45)
    _write(img, path)


def map_2d(path, groups: list[tuple[str, np.ndarray, tuple[int, int, int]]], title: str, scale: float = 30.0,
           segments: np.ndarray | None = None, poses: list[tuple[str, np.ndarray]] | None = None):
    """Top view.  groups: (label, points (N, 2+), BGR colour); segments (W, 4) drawn grey (walls)."""
    pts = np.vstack([g[1][:, :2] for g in groups if len(g[1])])
    if segments is not None and len(segments):
        pts = np.vstack([pts, segments[:, :2], segments[:, 2:]])
    lo, hi = pts.min(axis=0) - 1.0, pts.max(axis=0) + 1.0
    width, height = int((hi[0] - lo[0]) * scale) + 40, int((hi[1] - lo[1]) * scale) + 80

    def px(p):
        return int(20 + (p[0] - lo[0]) * scale), int(60 + (hi[1] - p[1]) * scale)

    img = _canvas(width, height)
    for s in segments if segments is not None else []:
        cv2.line(img, px(s[:2]), px(s[2:]), GREY, 2)
    for _label, p, colour in groups:
        for q in p:
            cv2.circle(img, px(q), 3, colour, -1, cv2.LINE_AA)
    for label, pose in poses or []:
        a = px(pose[:2])
        b = px(pose[:2] + 0.8 * np.array([np.cos(pose[2]), np.sin(pose[2])]))
        cv2.arrowedLine(img, a, b, BLACK, 2, cv2.LINE_AA, tipLength=0.3)
        _text(img, label, (a[0] + 4, a[1] + 16), 0.45)
    _legend(img, groups, title)
    _write(img, path)


def map_3d(path, groups: list[tuple[str, np.ndarray, tuple[int, int, int]]], title: str,
           azimuth: float = -0.6, elevation: float = 0.5, scale: float = 26.0):
    """Oblique 3-D view of points (N, 3) with a floor grid; groups as in :func:`map_2d`."""
    pts = np.vstack([g[1] for g in groups if len(g[1])])
    centre = pts.mean(axis=0)
    ca, sa, ce, se = np.cos(azimuth), np.sin(azimuth), np.cos(elevation), np.sin(elevation)

    def project(p):
        p = np.atleast_2d(p) - centre
        x = ca * p[:, 0] - sa * p[:, 1]
        depth = sa * p[:, 0] + ca * p[:, 1]
        y = ce * p[:, 2] - se * depth
        return np.column_stack([x, y]), depth

    xy, _ = project(pts)
    lo, hi = xy.min(axis=0) - 1.0, xy.max(axis=0) + 1.0
    width, height = int((hi[0] - lo[0]) * scale) + 40, int((hi[1] - lo[1]) * scale) + 80

    def px(q):
        return [(int(20 + (a - lo[0]) * scale), int(60 + (hi[1] - b) * scale)) for a, b in q]

    img = _canvas(width, height)
    pmin, pmax = pts.min(axis=0), pts.max(axis=0)
    for gx in np.arange(np.floor(pmin[0]), pmax[0] + 1, 2.0):
        a, b = px(project(np.array([[gx, pmin[1], 0], [gx, pmax[1], 0]]))[0])
        cv2.line(img, a, b, GREY, 1)
    for gy in np.arange(np.floor(pmin[1]), pmax[1] + 1, 2.0):
        a, b = px(project(np.array([[pmin[0], gy, 0], [pmax[0], gy, 0]]))[0])
        cv2.line(img, a, b, GREY, 1)
    everything = [(p, c) for _, ps, c in groups for p in ps]
    if everything:
        allp = np.array([p for p, _ in everything])
        cols = [c for _, c in everything]
        q, depth = project(allp)
        for k in np.argsort(-depth):                      # far first
            cv2.circle(img, px(q[k:k + 1])[0], 3, cols[k], -1, cv2.LINE_AA)
    _legend(img, groups, title)
    _write(img, path)
