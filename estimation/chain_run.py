"""One run of the unknown-association chain as its rounds (:mod:`estimation.name_chain`) and pairwise rounds
(:mod:`estimation.pairwise_rounds`) share it: :class:`ChainRun`, the log, noise model, filter configuration and
settings, the smoother as it stands (the run replaces it when the sighting offsets enter and when the naming adds
offset groups), the observer, and the steps both kinds of round take: the guard's verdict on the merge groups, the
merges and the known-ID filter's guess on merged names. Split out of :mod:`estimation.name_chain` in session 37 (B),
unchanged."""
from __future__ import annotations

import numpy as np

from estimation.chain_observer import ChainObserver
from estimation.chain_settings import ChainSettings
from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.fresh_start import names_guess
from estimation.merge_screens import audit_parts, guard_groups
from estimation.name_merging import NamedSmoother, merge_guarded
from estimation.named_smoothing import MergeRound
from estimation.noise_model import NoiseModel
from estimation.pass_matching import PassVerdict, name_pairs

__all__ = ["ChainRun"]


class ChainRun:
    """One run of the chain: its settings, its smoother as it stands, its observer and the pairwise rounds it has
    run (numbered on across calls of :func:`estimation.pairwise_rounds.pairwise_rounds`)."""

    def __init__(self, log: RangeBearingLog, noise: NoiseModel, config: FastSLAMConfig, settings: ChainSettings,
                 observer: ChainObserver):
        self.log, self.noise, self.config, self.settings, self.observer = log, noise, config, settings, observer
        self.smoother: NamedSmoother | None = None
        self.pairwise_done = 0

    def guess(self, merged_names: np.ndarray):
        """The known-ID filter's guess on merged names (no barcodes): ``reguess``' and ``fresh_start``'s start."""
        return names_guess(self.log, merged_names, self.noise, self.config, np.random.default_rng(self.settings.seed))

    def guard(self, label: str, current: MergeRound, covariance, used, covisible) -> list[PassVerdict] | None:
        guard = guard_groups(current, covariance, used, covisible)
        self.observer.guard_judged(label, current, covariance, used, covisible, guard)
        return guard.kept if self.settings.guard and guard.dropped else None

    def merge(self, current: MergeRound, used: list[PassVerdict], guarded: list[PassVerdict] | None, label: str, *,
              reguess=None, kept_covisible: bool = False, untestable: bool = True) -> MergeRound:
        """A round's merges (:func:`estimation.name_merging.merge_guarded`); the state kept (``current`` when none
        was). ``untestable``: with ``audit_parts``, whether the audit holds back the parts the map cannot test (the
        rounds) or only those it refuses (the pairwise rounds)."""
        s = self.settings
        audit = None
        if s.audit_parts is not None:
            def audit(before: MergeRound, attempt: MergeRound) -> set[int]:
                result = audit_parts(before, attempt, floor_m=s.audit_parts, untestable=untestable)
                if result is None:
                    return set()
                self.observer.audited(before, attempt, result)
                return result.held
        state, attempts = merge_guarded(self.smoother, current, name_pairs(used, current.named),
                                        None if guarded is None else name_pairs(guarded, current.named),
                                        depth=s.bisect, reguess=reguess, kept_covisible=kept_covisible,
                                        fresh_start=self.guess if s.fresh_start else None, audit=audit)
        self.observer.merged(label, current, attempts, state)
        if np.array_equal(state.names, current.names):      # the audit held every merge back: nothing kept
            return current
        return state
