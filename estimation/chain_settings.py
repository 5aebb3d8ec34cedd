"""The unknown-association chain's options: :class:`ChainSettings` (defaults: session 30's recipe), what
:func:`estimation.name_chain.run_chain` and its rounds read. Split out of :mod:`estimation.name_chain` in session 37
(B), unchanged."""
from __future__ import annotations

from dataclasses import dataclass

from estimation.landmark_smoother import HeadingDrift, HeadingLoss

__all__ = ["ChainSettings"]


@dataclass(frozen=True)
class ChainSettings:
    """Every option of the chain. Defaults: session 30's recipe (``benchmarks/mrclam_constellation.py``'s
    ``--max-rounds 9 --guard --sighting-offset 0.03 --offsets-once-tight --pairwise 6 --kept-covisible
    --split-ambiguous --honest-names 0.01 --honest-rounds --leave-out-ambiguous --leave-out-unconfirmed --slip 0.3
    --name-unnamed --fewer-rival --distinct-points --hold-two-points --runs-out``); the options sessions 25-35 measured
    and did not adopt (``split_bends``, ``mutual_rounds``, ``fresh_start``, ``audit_parts``, ``pairwise_alone``,
    ``heading_loss``, ``reguess``, ...) are off. Each field is the benchmark's option of the same name (its help
    says what it does and which session measured it)."""

    # the chained names (estimation.chained_names.chain_log) and the guess's filter (its random generator's seed)
    window_s: float = 40.0
    step_s: float | None = None           # None: half the window
    seed: int = 0
    # the smoother
    drift: tuple[float, float] = (0.16, 10.0)  # heading drift σ_b (rad/m), τ (s); σ_b 0 and slip 0: none
    slip: float = 0.3                     # heading slip σ per radian turned on the spot
    path_step_s: float = 0.25             # 0: the random walk's variance of the chord between sighting frames
    heading_loss: str = "gaussian"        # or "student-t"
    heading_dof: float = 3.0
    split_bends: bool = False
    # the rounds
    pass_seconds: float = 20.0
    min_sightings: int = 2
    min_pairs: int = 3
    ratio: float | None = None            # None: no rival allowed
    fewer_rival: bool = True
    distinct_points: bool = True
    rival_rounds: int | None = None       # None: the rival options in every round
    max_rounds: int = 9
    bisect: int = 2
    guard: bool = True
    honest_names: float | None = 0.01
    honest_rounds: bool = True
    hold_two_points: bool = True
    mutual_rounds: bool = False
    fresh_start: bool = False
    audit_parts: float | None = None      # the part audit's floor (m); None: off
    reguess: bool = False
    sighting_offset: float = 0.03         # σ (m) of an offset per chained name; 0: off
    offsets_once_tight: bool = True
    # after the rounds
    pairwise: int = 6
    kept_covisible: bool = True
    name_floor: float = 0.0
    split_ambiguous: bool = True
    pairwise_alone: bool = False
    leave_out_ambiguous: bool = True
    leave_out_unconfirmed: bool = True
    name_unnamed: bool = True
    runs_out: bool = True

    def __post_init__(self):
        if self.honest_names is not None and not 0 < self.honest_names < 1:
            raise ValueError(f"honest_names: α must be in (0, 1), not {self.honest_names}")
        needs = [(self.honest_rounds and self.honest_names is None, "honest_rounds needs honest_names"),
                 (self.hold_two_points and self.honest_names is None, "hold_two_points needs honest_names"),
                 (self.runs_out and (self.honest_names is None or not self.name_unnamed),
                  "runs_out needs honest_names and name_unnamed"),
                 (self.offsets_once_tight and not self.sighting_offset > 0, "offsets_once_tight needs sighting_offset"),
                 (self.rival_rounds is not None and not (self.fewer_rival or self.distinct_points),
                  "rival_rounds needs fewer_rival or distinct_points"),
                 (self.heading_loss not in ("gaussian", "student-t"), f"heading_loss {self.heading_loss!r}")]
        for wrong, why in needs:
            if wrong:
                raise ValueError(why)

    @property
    def heading_drift(self) -> HeadingDrift | None:
        """The smoother's heading drift (with the slip), or None when both are 0."""
        if self.drift[0] > 0 or self.slip > 0:
            return HeadingDrift(*self.drift, sigma_per_rad=self.slip)
        return None

    @property
    def path_step(self) -> float | None:
        """The increments' path step (s), or None for the chord's variance."""
        return self.path_step_s if self.path_step_s > 0 else None

    @property
    def loss(self) -> HeadingLoss | None:
        """The heading loss of every smoothing and cost, or None (Gaussian)."""
        return HeadingLoss("student-t", self.heading_dof) if self.heading_loss == "student-t" else None

    @property
    def offsets_from_start(self) -> bool:
        """Whether the sighting offsets are on from the chain's smoothing (else from when the map is tight)."""
        return self.sighting_offset > 0 and not self.offsets_once_tight

    def rival_options(self, round_number: int) -> dict:
        """``fewer_rival`` and ``distinct_points`` for round ``round_number``: off after ``rival_rounds``."""
        on = self.rival_rounds is None or round_number <= self.rival_rounds
        return {"fewer_rival": self.fewer_rival and on, "distinct_points": self.distinct_points and on}

