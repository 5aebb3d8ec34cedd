"""The support gate's scale from the supports' own residuals, in either direction.

What a map claims for a landmark is its error in the map's *start frame*: FastSLAM's export adds the drift of the
robot's pose when the landmark was made (``landmark_covariance: mixture+drift``), which NEES against the truth
measures and which the export must claim.  Most of that drift is shared by the landmarks one stretch of path made:
it moves a region of the map rigidly.  A correspondence gate is applied *after* a rigid transform has been fitted to
the overlap, and the residual left then is the part the transform cannot absorb: the landmarks' own (local) errors
and what varies of the drift across the overlap.  So the honest start-frame covariance can be many times wider than
the residuals a correct transform leaves (rendered demo, seed 0, with the drift lever: the true supports' normalised
squared residuals have a median 0.019 of χ²₂'s), and a gate built from it lets a distinct transform's loose
supports through (the building's half turn: 38 against 40).

``residual_gate_scale`` is the covariance scale that makes the median normalised squared residual of a hypothesis'
supports the median of χ²₂.  The ``"inflate"`` rule (the rule before session 8; still the paper preset's) only lets
it widen the gate (≥ 1: the covariances too small, MRCLAM's 4–7 mm); ``"residual"`` (the robust preset's) lets it
narrow the gate too, down to the preset's ``min_gate`` floor.  Either way the chance supports are counted with the
same final gate (decoys, rival, self-repeat), so a narrower gate cannot buy a "found": it asks for fewer supports only
because fewer fall in by chance.
"""
from __future__ import annotations

import numpy as np

# median of χ²₂: the scale of squared residuals normalised by their per-axis variance
CHI2_2_MEDIAN = 2.0 * np.log(2.0)
# "inflate": the claimed covariances are a lower bound (scale ≥ 1); "residual": the supports' residuals set the scale
GATE_SCALES = ("inflate", "residual")


def check_gate_scale(rule: str) -> str:
    if rule not in GATE_SCALES:
        raise ValueError(f"unknown gate_scale {rule!r} (choose from {', '.join(GATE_SCALES)})")
    return rule


def residual_gate_scale(residuals_xy: np.ndarray, var_xy: np.ndarray, rule: str = "inflate") -> float:
    """Covariance scale κ from residuals (K, 2) of a hypothesis' supports and their per-axis variances (K,):
    median(|r|² / var) / median(χ²₂); ``rule="inflate"`` keeps κ ≥ 1.  NaN for no supports."""
    check_gate_scale(rule)
    r = np.asarray(residuals_xy, float).reshape(-1, 2)
    v = np.asarray(var_xy, float).reshape(-1)
    if len(r) == 0:
        return float("nan")
    kappa = float(np.median(np.einsum("ki,ki->k", r, r) / v)) / CHI2_2_MEDIAN
    return max(1.0, kappa) if rule == "inflate" else kappa


def settled_scale(kappa: float, previous: float, step: int, rule: str = "inflate") -> float:
    """The scale a polishing round uses.  "inflate": ``kappa`` as measured (it only widens, so the re-gating
    settles).  "residual": the first round sets it freely; later rounds may only widen it, so that the supports
    cannot cycle between a narrower gate that drops some and a wider one that takes them back (MRCLAM robots 3-5:
    13 -> 12 -> 11 -> 13 supports, κ 0.034 -> 0.041 -> 0.081 -> 0.034, never settled)."""
    if rule == "residual" and step > 0:
        return max(kappa, previous)
    return kappa
