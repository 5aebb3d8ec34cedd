"""One entry point for every scan matcher: ``match_scans(reference, current, method=...)``."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from estimation.scanmatch.baselines import match_icp, match_plicp
from estimation.scanmatch.common import MatchConfig, MatchResult
from estimation.scanmatch.eicp import match_eicp, match_eicp_mesh
from estimation.scanmatch.errors import ScanMatchError
from estimation.scanmatch.scan import Scan2D

Matcher = Callable[[Scan2D, Scan2D, np.ndarray, MatchConfig], MatchResult]

#: Method name -> matcher.  "eicp-mesh" is eICP under the rigid-mesh (one arc-length shift) constraint.
METHODS: dict[str, Matcher] = {
    "eicp": match_eicp,
    "eicp-mesh": match_eicp_mesh,
    "icp": match_icp,
    "plicp": match_plicp,
}


def match_scans(reference: Scan2D, current: Scan2D, method: str = "eicp", initial=None,
                config: MatchConfig | None = None) -> MatchResult:
    """The pose (3,) of ``current`` in the frame of ``reference``, from ``initial`` (3,) (default: identity)."""
    if method not in METHODS:
        raise ScanMatchError(f"unknown scan-matching method {method!r}; choose one of {', '.join(METHODS)}")
    config = config or MatchConfig()
    if len(reference) < 2 or len(current) < max(config.min_correspondences, 3):
        raise ScanMatchError(f"too few points to match: reference {len(reference)}, current {len(current)}")
    initial = np.zeros(3) if initial is None else np.asarray(initial, dtype=float).reshape(3)
    return METHODS[method](reference, current, initial, config)
