"""Deterministic procedural textures of the simulated building, baked into one atlas image.

Every wall face (wall piece, side) is a strip of the atlas, ``resolution`` pixels per metre along the wall
(s) and down from the ceiling (z); each decoration is painted into its face from its own seed, so the same
building file always looks the same. Floor and ceiling are repeating tiles in their own corner of the atlas.
Albedo is stored as uint8 (0..255 = 0..1); the renderer samples it with ``cv2.remap`` (bilinear).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

MAX_ATLAS_WIDTH = 16000  # cv2.remap needs source sides below 32767
PAD = 2  # pixels between strips so that bilinear sampling never mixes two faces
FLOOR_TILE_M = 4.0  # size of the repeating floor/ceiling textures
FLOOR_RES = 64.0  # px/m of floor and ceiling textures
WALL_PAINT = 0.72


@dataclass(frozen=True)
class Atlas:
    """image: (H, W) uint8 albedo. face_x0/face_y0: (walls, 2) atlas pixel of (s=0, z=ceiling) of each face,
    index [wall, 0] for side -1 and [wall, 1] for side +1. floor_origin/ceiling_origin: atlas pixel of the
    (0, 0) corner of each tile; far_pixel: a uniform patch for rays that hit nothing."""

    image: np.ndarray
    resolution: float
    ceiling_height: float
    face_x0: np.ndarray
    face_y0: np.ndarray
    floor_origin: tuple[float, float]
    ceiling_origin: tuple[float, float]
    far_pixel: tuple[float, float]
    tile_pixels: int
    floor: np.ndarray  # (tile_pixels, tile_pixels) uint8, repeats every FLOOR_TILE_M metres
    ceiling: np.ndarray


def _rect(img: np.ndarray, r0: float, r1: float, c0: float, c1: float, value: float) -> None:
    h, w = img.shape
    a, b = max(0, int(round(r0))), min(h, int(round(r1)))
    c, d = max(0, int(round(c0))), min(w, int(round(c1)))
    if a < b and c < d:
        img[a:b, c:d] = value


def _frame(img: np.ndarray, border: float, value: float) -> None:
    h, w = img.shape
    _rect(img, 0, border, 0, w, value)
    _rect(img, h - border, h, 0, w, value)
    _rect(img, 0, h, 0, border, value)
    _rect(img, 0, h, w - border, w, value)


def _poster(h: int, w: int, rng: np.random.Generator, res: float) -> np.ndarray:
    img = np.full((h, w), rng.uniform(0.55, 0.95))
    for _ in range(int(rng.integers(6, 14))):
        r0, c0 = rng.uniform(0.05, 0.8) * h, rng.uniform(0.05, 0.8) * w
        _rect(img, r0, r0 + rng.uniform(0.08, 0.4) * h, c0, c0 + rng.uniform(0.08, 0.4) * w, rng.uniform(0.05, 0.95))
    _text_lines(img, rng, res, rows=(0.82, 0.95), dark=rng.uniform(0.05, 0.3))
    _frame(img, 0.015 * res, 0.12)
    return img


def _text_lines(img: np.ndarray, rng: np.random.Generator, res: float, rows: tuple[float, float], dark: float) -> None:
    h, w = img.shape
    line = max(2.0, 0.012 * res)
    r = rows[0] * h
    while r + line < rows[1] * h:
        c = 0.08 * w
        while c < 0.9 * w:
            length = rng.uniform(0.02, 0.09) * res
            _rect(img, r, r + line, c, min(c + length, 0.9 * w), dark)
            c += length + 0.015 * res
        r += 2.2 * line


def _notice(h: int, w: int, rng: np.random.Generator, res: float) -> np.ndarray:
    img = np.full((h, w), 0.93)
    _rect(img, 0.06 * h, 0.16 * h, 0.08 * w, rng.uniform(0.5, 0.9) * w, 0.15)  # title bar
    _text_lines(img, rng, res, rows=(0.24, 0.9), dark=0.2)
    _frame(img, 0.004 * res, 0.55)
    return img


def _window(h: int, w: int, rng: np.random.Generator, res: float) -> np.ndarray:
    rows = np.linspace(0.0, 1.0, h)[:, None]
    img = np.broadcast_to(0.5 + 0.35 * rows + rng.uniform(-0.05, 0.05), (h, w)).copy()  # sky-lit glass
    border, bar = 0.06 * res, 0.04 * res
    _frame(img, border, 0.22)
    _rect(img, 0, h, w / 2 - bar / 2, w / 2 + bar / 2, 0.22)
    _rect(img, h / 2 - bar / 2, h / 2 + bar / 2, 0, w, 0.22)
    return img


def _door(h: int, w: int, rng: np.random.Generator, res: float) -> np.ndarray:
    grain = rng.normal(0.0, 0.03, size=w).cumsum()
    grain = (grain - grain.mean()) / max(1e-6, np.ptp(grain)) * 0.08
    img = np.broadcast_to(rng.uniform(0.35, 0.55) + grain[None, :], (h, w)).copy()
    for r0, r1 in ((0.08, 0.45), (0.55, 0.92)):  # two recessed panels
        _frame_rect(img, r0 * h, r1 * h, 0.15 * w, 0.85 * w, 0.01 * res, 0.2)
    handle_row = h - 1.0 * res
    _rect(img, handle_row - 0.03 * res, handle_row + 0.03 * res, 0.82 * w, 0.82 * w + 0.12 * res, 0.08)
    _frame(img, 0.05 * res, 0.25)
    return img


def _frame_rect(img: np.ndarray, r0: float, r1: float, c0: float, c1: float, t: float, value: float) -> None:
    _rect(img, r0, r0 + t, c0, c1, value)
    _rect(img, r1 - t, r1, c0, c1, value)
    _rect(img, r0, r1, c0, c0 + t, value)
    _rect(img, r0, r1, c1 - t, c1, value)


def _door_frame(h: int, w: int, rng: np.random.Generator, res: float) -> np.ndarray:
    img = np.full((h, w), 0.28)
    _rect(img, 0, h, 0, max(1.0, 0.01 * res), 0.12)
    return img


def _baseboard(h: int, w: int, rng: np.random.Generator, res: float) -> np.ndarray:
    img = np.full((h, w), 0.2)
    _rect(img, 0, max(1.0, 0.01 * res), 0, w, 0.4)
    return img


def _generic(h: int, w: int, rng: np.random.Generator, res: float) -> np.ndarray:
    img = np.full((h, w), rng.uniform(0.3, 0.9))
    for _ in range(int(rng.integers(3, 8))):
        r0, c0 = rng.uniform(0, 0.8) * h, rng.uniform(0, 0.8) * w
        _rect(img, r0, r0 + rng.uniform(0.1, 0.5) * h, c0, c0 + rng.uniform(0.1, 0.5) * w, rng.uniform(0.05, 0.95))
    return img


PAINTERS: dict[str, Callable[[int, int, np.random.Generator, float], np.ndarray]] = {
    "poster": _poster, "notice": _notice, "window": _window, "door": _door, "door_frame": _door_frame,
    "baseboard": _baseboard,
}


def _wall_paint(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Light paint with gentle low-frequency variation (plain, like a real corridor)."""
    coarse = rng.normal(0.0, 1.0, size=(max(2, h // 40 + 2), max(2, w // 40 + 2))).astype(np.float32)
    smooth = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    return WALL_PAINT + 0.03 * smooth


def _floor_tile(n: int, rng: np.random.Generator) -> np.ndarray:
    tiles = int(FLOOR_TILE_M / 0.5)
    shades = rng.uniform(0.35, 0.5, size=(tiles, tiles))
    img = np.kron(shades, np.ones((n // tiles, n // tiles)))
    grout = max(1, n // tiles // 16)
    for k in range(tiles):
        img[k * (n // tiles):k * (n // tiles) + grout, :] = 0.18
        img[:, k * (n // tiles):k * (n // tiles) + grout] = 0.18
    return img + rng.normal(0.0, 0.02, size=img.shape)


def _ceiling_tile(n: int, rng: np.random.Generator) -> np.ndarray:
    img = np.full((n, n), 0.8)
    panel = n // int(FLOOR_TILE_M / 0.6 + 0.5)
    for k in range(0, n, panel):
        img[k:k + 1, :] = 0.6
        img[:, k:k + 1] = 0.6
    light = n // 4
    img[n // 2 - light // 2:n // 2 + light // 2, n // 4:n // 4 + panel] = 1.0
    return img + rng.normal(0.0, 0.01, size=img.shape)


def build_atlas(walls: np.ndarray, decorations: list, ceiling_height: float, resolution: float = 100.0,
                seed: int = 0) -> Atlas:
    """Bake every face of ``walls`` (W, 4) with its decorations into one atlas (see ``Atlas``)."""
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    face_rows = int(math.ceil(ceiling_height * resolution)) + 1
    band_h = face_rows + 2 * PAD
    face_x0 = np.zeros((len(walls), 2))
    face_y0 = np.zeros((len(walls), 2))
    # Pack faces left to right into bands.
    x, band, placements = PAD, 0, []
    for wall in range(len(walls)):
        cols = int(math.ceil(lengths[wall] * resolution)) + 1
        if cols + 2 * PAD > MAX_ATLAS_WIDTH:
            raise ValueError(f"wall {wall} is too long ({lengths[wall]:.1f} m) for the texture atlas")
        for side_index in (0, 1):
            if x + cols + PAD > MAX_ATLAS_WIDTH:
                x, band = PAD, band + 1
            placements.append((wall, side_index, x, band * band_h + PAD, cols))
            face_x0[wall, side_index], face_y0[wall, side_index] = x, band * band_h + PAD
            x += cols + 2 * PAD
    n = int(FLOOR_TILE_M * FLOOR_RES)
    tiles_y0 = (band + 1) * band_h
    width = MAX_ATLAS_WIDTH if band > 0 else max(x, 3 * (n + 2 * PAD) + 16)
    width = max(width, 3 * (n + 2 * PAD) + 16)
    atlas = np.zeros((tiles_y0 + n + 2 * PAD, width), np.float32)
    by_face: dict[tuple[int, int], list] = {}
    for deco in decorations:
        by_face.setdefault((int(deco.wall), 1 if deco.side > 0 else 0), []).append(deco)
    for wall, side_index, x0, y0, cols in placements:
        rng = np.random.default_rng([seed, wall, side_index])
        face = _wall_paint(face_rows + 2 * PAD, cols + 2 * PAD, rng)
        for deco in sorted(by_face.get((wall, side_index), []), key=lambda d: d.kind != "baseboard"):
            r0 = PAD + (ceiling_height - deco.z1) * resolution
            r1 = PAD + (ceiling_height - deco.z0) * resolution
            c0, c1 = PAD + deco.s0 * resolution, PAD + deco.s1 * resolution
            a, b, c, d = int(round(r0)), int(round(r1)), int(round(c0)), int(round(c1))
            a, c = max(a, 0), max(c, 0)
            b, d = min(b, face.shape[0]), min(d, face.shape[1])
            if b <= a or d <= c:
                continue
            painter = PAINTERS.get(deco.kind, _generic)
            face[a:b, c:d] = painter(b - a, d - c, np.random.default_rng(int(deco.seed) & 0xFFFFFFFF), resolution)
        atlas[y0 - PAD:y0 - PAD + face.shape[0], x0 - PAD:x0 - PAD + face.shape[1]] = face
    rng = np.random.default_rng([seed, 1 << 20])
    floor = np.pad(_floor_tile(n, rng), PAD, mode="wrap")
    ceiling = np.pad(_ceiling_tile(n, rng), PAD, mode="wrap")
    atlas[tiles_y0:tiles_y0 + floor.shape[0], 0:floor.shape[1]] = floor
    cx0 = floor.shape[1] + 4
    atlas[tiles_y0:tiles_y0 + ceiling.shape[0], cx0:cx0 + ceiling.shape[1]] = ceiling
    far_x = cx0 + ceiling.shape[1] + 4
    atlas[tiles_y0:tiles_y0 + 8, far_x:far_x + 8] = 0.5
    image = np.clip(atlas * 255.0 + 0.5, 0, 255).astype(np.uint8)
    tile = lambda y0, x0: np.ascontiguousarray(image[y0 + PAD:y0 + PAD + n, x0 + PAD:x0 + PAD + n])  # noqa: E731
    return Atlas(image, resolution, ceiling_height, face_x0, face_y0, (PAD, tiles_y0 + PAD),
                 (cx0 + PAD, tiles_y0 + PAD), (far_x + 4.0, tiles_y0 + 4.0), n, tile(tiles_y0, 0),
                 tile(tiles_y0, cx0))
