"""The alignment's parameters: :class:`AlignmentConfig` and its two presets, ``paper`` (the ISR 2009 paper's values,
kept as published) and ``robust`` (the decision on the alignment's own evidence; see :mod:`fusion.alignment`).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

from .errors import IncompatibleMapsError


@dataclass(frozen=True)
class AlignmentConfig:
    """Parameters of the RANSAC alignment.  ``paper`` and ``robust`` are the two presets."""

    name: str
    descriptor_threshold: float          # th0: largest accepted descriptor distance
    ratio: float | None                  # Lowe ratio test + mutual matches; None = the paper's nearest match
    pair_tolerance: float                # paper: th1 on |d'² − d²| (m²); robust: in σ of |d' − d|
    min_pair_separation: float           # metres; shorter pairs fix no angle
    support_threshold: float             # th2, metres (Euclidean 3-D; robust: largest gate radius)
    min_supports: int                    # `min` (paper: the decision; robust: a floor, the evidence decides)
    iterations: int                      # M (paper) or the cap of the adaptive count (robust)
    adaptive: bool = False               # iteration count from the inlier ratio and `confidence`
    confidence: float = 0.999
    min_iterations: int = 32
    covariance_gating: bool = False      # gates from the landmark covariances instead of th2
    refine: bool = False                 # weighted least squares on all supports + covariance
    significance: float | None = None    # largest accepted false-alarm probability of the supports
    min_spread: float = 0.0              # metres, principal standard deviation of the supports (xy)
    position_floor: float = 0.02         # metres, added in quadrature to every landmark's std
    min_gate: float = 0.0                # metres, smallest support-gate radius in the plane
    inflate_gate: bool = False           # scale the gate by the supports' own residuals (see module doc)
    decoys: int = 1000                   # decoy transforms scored to measure the chance supports
    gate_scale: str = "inflate"          # "residual": the supports' residuals may also narrow it (fusion.gate_scale)
    # where a map's repeat of itself is counted: "own", in the gate its own covariances give (capped at
    # support_threshold); "pair", in the pair's final gate scale, as the decoys and the rival are (see self_structure)
    self_repeat_gate: str = "own"
    # two robots cannot be in one place at one time (fusion/colocation.py, session 12; option, off): an alignment that
    # puts the robots' bodies together at a common time is not found, and a rival that does is no rival
    colocation: bool = False
    # whose ratio test a mutual best match must pass (fusion.matching.RATIO_SIDES; session 45): "map1", map 1's
    # landmark's only (both presets); "both" or "either" landmark's (symmetric_correspondences), so that align(A, B)
    # and align(B, A) start from the same correspondences, swapped
    ratio_sides: str = "map1"
    # the law of a wrong hypothesis' chance supports (fusion.evidence.CHANCE_MODELS; session 51, option): "poisson",
    # the decoys' rate; "negative_binomial", the decoys' rate and their overdispersion (variance / mean)
    chance_model: str = "poisson"
    # decoys scored for the dispersion's bound under chance_model "negative_binomial" (`decoys` of them are the rate's,
    # as under "poisson"; session 52): the bound needs the rare decoys that gather many supports, 1,000 hold few or none
    dispersion_decoys: int = 20_000

    def to_dict(self) -> dict:
        return asdict(self)


PAPER = AlignmentConfig(
    name="paper", descriptor_threshold=2.0, ratio=None, pair_tolerance=2.0, min_pair_separation=0.0,
    support_threshold=0.2, min_supports=20, iterations=70,
)
# min_supports 4: two supports define a hypothesis, two more are the least that can check it; above that
# the false-alarm probability decides (10⁻⁶, Bonferroni-corrected).  min_gate 0.3 m: a landmark's position
# in its robot's start frame is rarely better than a few decimetres once the robot's pose error is counted,
# which FastSLAM's per-particle covariances leave out (MRCLAM: 4–7 mm claimed, 0.04–0.27 m real).  gate_scale
# "residual": honest start-frame covariances hold drift the transform removes, so the supports' residuals may also
# narrow the gate to that floor (fusion/gate_scale.py; docs/fusion-history.md "Session 8: the alignment's gate").
ROBUST = AlignmentConfig(
    name="robust", descriptor_threshold=0.8, ratio=0.8, pair_tolerance=3.0, min_pair_separation=0.5,
    support_threshold=1.0, min_supports=4, iterations=2000, adaptive=True, confidence=0.9999,
    covariance_gating=True, refine=True, significance=1e-6, min_spread=0.3, min_gate=0.3, inflate_gate=True,
    gate_scale="residual", self_repeat_gate="pair",
)
PRESETS: dict[str, AlignmentConfig] = {"paper": PAPER, "robust": ROBUST}


def resolve_preset(preset: str | AlignmentConfig) -> AlignmentConfig:
    """The configuration a preset name stands for (a configuration is its own); an unknown name is refused."""
    if isinstance(preset, AlignmentConfig):
        return preset
    try:
        return PRESETS[preset]
    except KeyError:
        raise IncompatibleMapsError(f"unknown alignment preset {preset!r} (choose from {sorted(PRESETS)})") from None
