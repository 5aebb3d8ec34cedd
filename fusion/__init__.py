"""Map fusion: RANSAC alignment of landmark maps and Kalman merging (ISR 2009 paper, Sections 3–4).

    align(map1, map2, preset="robust", rng=...) -> Alignment       # pose of map 2's frame in map 1's
    merge(map1, map2, alignment, method=1) -> LandmarkMap           # in map 1's frame
    fuse_all(maps, preset="robust", method=1, rng=..., cache=AlignmentCache()) -> MultiFusion
"""
from __future__ import annotations

from .alignment import Alignment, AlignmentStatistics, align, alignment_error, true_relative_pose, truth_heading
from .alignment_config import PAPER, PRESETS, ROBUST, AlignmentConfig
from .cache import AlignmentCache
from .errors import FusionError, IncompatibleMapsError, NoOverlapError
from .fingerprint import map_fingerprint
from .merging import common_landmarks, kalman_fuse, merge, merge_pairs
from .multi import MultiFusion, fuse_all

__all__ = [
    "PAPER", "PRESETS", "ROBUST", "Alignment", "AlignmentCache", "AlignmentConfig", "AlignmentStatistics",
    "FusionError", "IncompatibleMapsError", "MultiFusion", "NoOverlapError", "align", "alignment_error",
    "common_landmarks", "fuse_all", "kalman_fuse", "map_fingerprint", "merge", "merge_pairs", "true_relative_pose",
    "truth_heading",
]
