"""Fixtures for the scan-matching tests: a polygonal room and an exact ray-casting laser inside it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

# A non-convex (L-shaped, with an alcove) room, counter-clockwise vertices in metres.
ROOM = np.array([[-3.0, -2.5], [4.0, -2.5], [4.0, 0.5], [2.5, 0.5], [2.5, 3.0], [0.5, 3.0], [0.5, 2.2],
                 [-1.0, 2.2], [-1.0, 3.0], [-3.0, 3.0]])

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


def cast_rays(origin: np.ndarray, bearings: np.ndarray, polygon: np.ndarray = ROOM) -> np.ndarray:
    """Exact ranges (B,) from ``origin`` (2,) along world bearings (B,) to the nearest polygon edge."""
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    d = np.column_stack([np.cos(bearings), np.sin(bearings)])            # (B, 2)
    e = b - a                                                           # (E, 2)
    w = a - origin                                                      # (E, 2)
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (B, E)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / denom
        u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    return np.min(np.where(hit, t, np.inf), axis=1)


def simulate_laser(pose, n_beams: int = 180, fov: float = np.pi) -> np.ndarray:
    """Ranges (n_beams,) of a laser at ``pose`` (3,) in ROOM, beams from -fov/2 to +fov/2."""
    angles = -fov / 2 + fov * np.arange(n_beams) / (n_beams - 1)
    return cast_rays(np.asarray(pose[:2], float), pose[2] + angles)


@pytest.fixture
def room():
    return ROOM


@pytest.fixture
def laser():
    return simulate_laser


@pytest.fixture
def ray_caster():
    return cast_rays


@pytest.fixture
def laser_data_dir():
    folder = DATA / "laser"
    if not (folder / "aces-corrected.log.gz").is_file():
        pytest.skip(f"real laser logs not found in {folder.resolve()} (../shared/data/laser)")
    return folder
