"""What a caller of the unknown-association chain (:func:`estimation.name_chain.run_chain`) is told as it runs:
:class:`ChainObserver`, one no-op hook per decision. The chain reads neither the barcodes nor the ground truth; a
caller scores it through these hooks (``benchmarks/mrclam_constellation.py``'s ``_Recorder`` records and scores them
all). Split out of :mod:`estimation.name_chain` in session 37 (B), unchanged."""
from __future__ import annotations

import numpy as np

from estimation.map_honesty import Run
from estimation.merge_screens import Guard, PartAudit
from estimation.name_merging import NamedSmoother
from estimation.named_smoothing import MergeRound
from estimation.pass_matching import PassVerdict

__all__ = ["ChainObserver"]


class ChainObserver:
    """What a caller is told as the chain runs: every hook has a no-op default. ``number`` is a round's (counted from
    the chain) or a pairwise round's; ``before`` a step's state before it. The states are the chain's own: read
    them, do not change them."""

    def chain_smoothed(self, state: MergeRound, smoother: NamedSmoother) -> None:
        """The chained names' first smoothing (not called when resuming)."""

    def split_tried(self, split: dict) -> None:
        """A split at a bend measured (``split_bends``)."""

    def splits_done(self, before: MergeRound, after: MergeRound, tried: list[dict]) -> None:
        """The splits at bends applied (``split_bends``)."""

    def resumed(self, state: MergeRound, round_done: int, offsets: bool) -> None:
        """A run from a saved state starts (``offsets``: it was re-smoothed with the sighting offsets first)."""

    def state_kept(self, tag: str, state: MergeRound, round_done: int, smoother: NamedSmoother,
                   before: MergeRound | None) -> None:
        """A state to keep: ``round0`` (the chain's), ``round<k>``, ``pairwise<k>`` (``round_done`` −k),
        ``out-ambiguous``/``out-unconfirmed`` (``round_done`` −1)."""

    def round_begins(self, number: int, state: MergeRound, smoother: NamedSmoother) -> None:
        """A round starts."""

    def round_judged(self, number: int, state: MergeRound, verdicts: list[PassVerdict]) -> None:
        """The passes judged (before any screen)."""

    def honest_screened(self, number: int, state: MergeRound, verdicts: list[PassVerdict], flagged: np.ndarray
                        ) -> None:
        """``honest_rounds``: the names the screen flags (their pairings in ``verdicts`` are held back)."""

    def mutual_aside(self, number: int, state: MergeRound, aside: list) -> None:
        """``mutual_rounds``: the clusters set aside, not all within each other's gate."""

    def round_proposed(self, number: int, state: MergeRound, used: list[PassVerdict]) -> None:
        """The passes whose pairings the round would merge."""

    def guard_judged(self, label: str, state: MergeRound, covariance: np.ndarray, used: list[PassVerdict],
                     covisible: np.ndarray, guard: Guard) -> None:
        """The guard's verdict (``label``: "round k" or "pairwise k"; acted on only with ``guard``)."""

    def audited(self, before: MergeRound, attempt: MergeRound, audit: PartAudit) -> None:
        """``audit_parts``: a kept batch audited."""

    def merged(self, label: str, before: MergeRound, attempts: list[MergeRound], state: MergeRound) -> None:
        """A round's or pairwise round's merges: every attempt, and the state they end in."""

    def offsets_entered(self, after_round: int, state: MergeRound) -> None:
        """``offsets_once_tight``: the offsets entered after round ``after_round``, the state re-smoothed."""

    def pairwise_begins(self, number: int, state: MergeRound) -> None:
        """A pairwise round starts."""

    def pairwise_grouped(self, number: int, state: MergeRound, groups: list) -> None:
        """The pairwise groups (every status)."""

    def pairwise_honest(self, number: int, state: MergeRound, flagged: np.ndarray, held: list) -> None:
        """``honest_names``: the flagged names and the merge groups held back for them."""

    def alone_checked(self, number: int, state: MergeRound, used: list[PassVerdict], rises: list[float],
                      absorbed: list[int], refused: np.ndarray) -> None:
        """``pairwise_alone``: each group's own rise and whether it was refused."""

    def pairwise_proposed(self, number: int, state: MergeRound, used: list[PassVerdict]) -> None:
        """The groups the pairwise round would merge (empty: the pairwise rounds end)."""

    def runs_flagged(self, key: str, before: MergeRound, flagged: list[tuple[Run, float, float]]) -> None:
        """``runs_out``: the flagged runs taken out (``key``: "runs_out_before_pairwise" or "runs_out")."""

    def left_out(self, why: str, before: MergeRound, left: list[int], after: MergeRound) -> None:
        """Names left out (``why``: "ambiguous" or "unconfirmed")."""

    def named_again(self, key: str, before: MergeRound, after: MergeRound, proposed: dict[int, int]) -> None:
        """Unnamed sightings named (``key``: "named_again" or "named_after_runs_out")."""
