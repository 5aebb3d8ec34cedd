"""Fusion tests: the map simulator lives in benchmarks/fusion_sim.py (shared with the evaluation scripts)."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

_BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
if str(_BENCHMARKS) not in sys.path:
    sys.path.insert(0, str(_BENCHMARKS))


@pytest.fixture(scope="session")
def sim():
    """The ``fusion_sim`` module: building_pair, non_overlapping_pair, random_pair, true_common, ..."""
    return importlib.import_module("fusion_sim")
