"""Does the map still know where it is? A sequential test of the old map's re-detections (session 7).

A map that is confidently wrong is the worst output. FastSLAM's particles cannot tell: after a stretch in which
the map did not hold the pose (a turn on the spot facing a near wall, docs/fastslam-history.md "Rendered: why robot 2
diverges"), the cloud can settle around a wrong heading with a normal spread, ESS and association counts, and the
map after the stretch is built, consistently with itself, in a turned frame. What does show it is the map made
*before* the stretch: the best particle predicts its landmarks in view, and they are not re-detected.

The test, per frame, on the most probable particle (read only: the filter's estimates are unchanged):

- *Old landmarks*: confirmed (seen ≥ ``confirm_count`` times before this frame) and made before the latest frame
  in which the map did not hold the pose. A 3-D point (or a range-bearing reading) fixes two of a planar pose's
  three degrees of freedom, so a frame whose best particle matched fewer than two landmarks leaves the pose to
  the motion model: a gap. Landmarks made after the last gap move with whatever pose the filter took through
  it, so re-detecting them says nothing about the tie to the map before it; they are left out.
- *Predicted in view*: the existence model's own test (``miss_fov_margin`` of the field of view and range, the
  frame's reach when the observations were capped), at the best particle's pose.
- *Re-detectable*: with descriptors deciding the association, only landmarks seen now from within
  ``DESCRIPTOR_RANGE_RATIO`` of the range and ``DESCRIPTOR_VIEW_ANGLE`` of the direction they were made from: the
  fixed-scale upright descriptor of a point seen from 1.5-1.8× its first range is farther than the association
  threshold from its first one in most sightings (median 0.52 > 0.5, docs/fastslam-history.md "Descriptors per viewing
  range"), and local descriptors of a planar patch stop matching beyond ~40-50° of viewpoint change (Mikolajczyk
  et al. 2005, Bay et al. 2008). Outside those, the map's own association cannot re-detect a landmark that is
  there, so its miss says nothing. By identity (or without descriptors) every landmark in view is re-detectable.
- Each such landmark is, under H0 "the map is where the particle says", re-detected with the sensor's
  probability P_D(r) (``existence.detection_probability_or_constant``: the measured rates, or the constants'
  P_D = 1 − exp(existence_miss)); under H1 "the map lost its place" nothing is where it is predicted, and the
  association re-detects it only by chance: with descriptors, when an unrelated point's descriptor passes the
  threshold, ``DESCRIPTOR_CHANCE_MATCH`` (2–2.5 % of random pairs of the front end's descriptors are under 0.5,
  docs/fastslam-history.md "Rendered frames"; the diverged replay re-detects 1.4 %); by identity or without descriptors,
  as a false alarm, the existence model's P_FA (``false_alarm_probability``, or the constants' P_FA = P_D /
  exp(existence_hit)). That is the existence test applied to the old map as a whole. (With the constants' P_FA =
  0.14 as the descriptor path's H1, healthy stretches re-detecting 10 % of the old landmarks in view drove the
  statistic to 10.8 of 11.5; with 0.025, 6.7, and the diverged replay is flagged 13 s sooner.)
- A frame's log-likelihood ratio H1 : H0 is the sum over its old landmarks in view, each step discounted by the
  detections' lag-1 correlation like every existence step (``existence.evidence_per_frame``), and a capped
  frame's misses by the share of observations kept (as the existence model weighs them).
- Landmarks of one frame are not independent (one view, one pose error, one lighting): in healthy rendered runs
  whole frames re-detect 10 % of 40-90 old landmarks. The frame's ratio is divided by the detections'
  over-dispersion φ (quasi-likelihood, McCullagh & Nelder 1989, ch. 4): Pearson's χ² of the frames' counts about
  the pooled rate, per degree of freedom (φ ≥ 1), estimated online from the run's own frames *in control*: a
  frame enters the estimate once the CUSUM is back at 0 after it, and the frames of an excursion that ends in an
  alarm never do (else a map that lost its place would teach the check that missing everything is normal). Until
  ``MIN_DISPERSION_FRAMES`` such frames (the relative standard error of the estimate, √(2/F), is then ≤ 1/2), a
  frame counts as one landmark (φ = its count), the fully correlated extreme.
- CUSUM (Page 1954): S_t = max(0, S_{t−1} + ℓ_t); S_t ≥ h flags "the map lost its place at t". With ℓ a true
  log-likelihood ratio (a discounted one only lowers E_H0[e^ℓ]), the mean number of frames between false alarms
  is at least e^h (Lorden 1971), so h = ln(1 / α) for a stated false-alarm rate α per frame
  (``FastSLAMConfig.self_check_false_alarm``, default 1e-5: one false flag in 10⁵ frames, 7.4 h at 3.75 Hz).
  After an alarm S restarts from 0, so a second episode is flagged again.

The verdict (:meth:`SelfCheck.verdict`, a map's ``metadata["self_check"]``) is bounded: the first
``MAX_ALARMS`` alarms with their times and figures, and totals. An alarm's ``first_id_after_gap`` splits the map:
landmarks with a lower id were made before the gap the test was measuring against (the part the alarm says the
rest is no longer tied to), those from it on after it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import FastSLAMConfig
from .existence import detection_probability_or_constant, evidence_per_frame, false_alarm_probability_or_constant

KEY = "self_check"            # the map metadata key
VERSION = 1
MAX_ALARMS = 20               # alarms kept in a verdict (the count of all of them is kept too)
POSE_CONSTRAINING_MATCHES = 2  # one point fixes 2 of the planar pose's 3 degrees of freedom: two fix it
MIN_DISPERSION_FRAMES = 8      # √(2/F) ≤ 1/2: the dispersion estimate is trusted from then on
DESCRIPTOR_CHANCE_MATCH = 0.025  # H1's re-detection rate with descriptors (module docstring)
DESCRIPTOR_RANGE_RATIO = 1.5   # see the module docstring: where a descriptor's re-detection fails
DESCRIPTOR_VIEW_ANGLE = math.pi / 4


@dataclass
class FrameEvidence:
    """One frame's old landmarks predicted well in view by the best particle: how many, how many re-detected,
    how many H0 expects, and the log-likelihood ratio "lost" : "consistent" they carry."""

    t: float
    predicted: int
    redetected: int
    expected: float
    log_ratio: float              # after the dispersion's discount
    dispersion: float = 1.0


class SelfCheck:
    """The per-frame test of the module docstring; :meth:`observe` once per filter update."""

    def __init__(self, config: FastSLAMConfig, keep_history: bool = False) -> None:
        self.config = config
        self.threshold = math.log(1.0 / config.self_check_false_alarm)   # h = ln(1/α) (Lorden's bound)
        self.statistic = 0.0           # S_t
        self.reference_ids = 0         # landmarks with an id below this were made before the latest gap
        self.frames = 0
        self.frames_tested = 0
        self.predicted = 0
        self.redetected = 0
        self.expected = 0.0
        self.max_statistic, self.max_statistic_t = 0.0, None
        self.alarms: list[dict] = []
        self.n_alarms = 0
        self._onset: dict | None = None   # the frame S last left 0, with the figures summed since
        self.history: list[FrameEvidence] | None = [] if keep_history else None
        self._in_control = np.zeros(4)   # Σ k²/n, Σ k, Σ n, frames in control: χ² about any pooled rate
        self._excursion = np.zeros(4)    # the same over the frames since the CUSUM last left 0
        self.dispersion = 1.0
        # the planar range and world bearing each landmark id was made from (nan: unknown, e.g. a prior map's)
        self._made = np.full((0, 2), np.nan)
        self._by_view = config.association == "unknown" and config.descriptor_size > 0

    def made(self, ids: np.ndarray, z: np.ndarray, pose: np.ndarray) -> None:
        """New landmarks ``ids`` (N,) (-1: none) made from base_link points ``z`` (N, 3) at ``pose`` (3,)."""
        ids = np.asarray(ids, np.int64)
        keep = ids >= 0
        if not keep.any():
            return
        need = int(ids.max()) + 1
        if need > len(self._made):
            grown = np.full((max(need, 2 * len(self._made)), 2), np.nan)
            grown[: len(self._made)] = self._made
            self._made = grown
        ox, oy, _ = self.config.sensor_offset
        dx, dy = z[keep, 0] - ox, z[keep, 1] - oy
        self._made[ids[keep]] = np.column_stack([np.hypot(dx, dy), pose[2] + np.arctan2(dy, dx)])

    def _redetectable(self, ids: np.ndarray, ranges: np.ndarray, bearings: np.ndarray) -> np.ndarray:
        """(N,) bool: seen now from where the map's association could re-detect them (module docstring)."""
        if not self._by_view:
            return np.ones(len(ids), bool)
        inside = ids < len(self._made)
        made = np.full((len(ids), 2), np.nan)
        made[inside] = self._made[ids[inside]]
        ratio = ranges / made[:, 0]
        turn = np.abs(np.angle(np.exp(1j * (bearings - made[:, 1]))))
        near_scale = (ratio < DESCRIPTOR_RANGE_RATIO) & (ratio > 1.0 / DESCRIPTOR_RANGE_RATIO)
        return near_scale & (turn < DESCRIPTOR_VIEW_ANGLE)

    def observe(self, t: float, detected: tuple[np.ndarray, ...], missed: tuple[np.ndarray, ...], n_matched: int,
                n_ids: int, miss_weight: float = 1.0) -> FrameEvidence:
        """One frame of the best particle: ``detected`` = (ids, counts before this frame, planar ranges m, world
        bearings rad) of the landmarks it matched and predicts well in view, ``missed`` the same of those well in
        view it did not match; ``n_matched`` all its matches this frame; ``n_ids`` the ids that existed before
        this frame's new landmarks; ``miss_weight`` the share of the frame's observations kept (capped frames)."""
        cfg = self.config
        old_d = self._old(*detected[:2]) & self._redetectable(detected[0], *detected[2:])
        old_m = self._old(*missed[:2]) & self._redetectable(missed[0], *missed[2:])
        r_d, r_m = detected[2][old_d], missed[2][old_m]
        p_d = np.clip(detection_probability_or_constant(cfg, np.concatenate([r_d, r_m])), 1e-6, 1 - 1e-6)
        p_fa = (np.full(len(p_d), DESCRIPTOR_CHANCE_MATCH) if self._by_view else
                np.clip(false_alarm_probability_or_constant(cfg, p_d), 1e-6, 1 - 1e-6))
        n_d = len(r_d)
        hit = np.log(p_fa[:n_d] / p_d[:n_d]).sum()                       # detected: P_FA / P_D
        miss = np.log1p(-p_fa[n_d:]).sum() - np.log1p(-p_d[n_d:]).sum()  # missed: (1 − P_FA) / (1 − P_D)
        n = n_d + len(r_m)
        phi = self._dispersion(n)
        if n:
            self._excursion += (n_d * n_d / n, n_d, n, 1)
        evidence = FrameEvidence(float(t), n, n_d, float(p_d.sum()),
                                 float(evidence_per_frame(cfg) * (hit + miss_weight * miss)) / phi, phi)
        self._accumulate(evidence)
        self.frames += 1
        if n_matched < POSE_CONSTRAINING_MATCHES:   # a gap: what is made from now on moves with its pose
            self.reference_ids = max(self.reference_ids, int(n_ids))
        if self.history is not None:
            self.history.append(evidence)
        return evidence

    def _dispersion(self, n: int) -> float:
        """φ for a frame of n old landmarks in view, from the frames in control so far (module docstring)."""
        k2n, sk, sn, frames = self._in_control
        if n == 0 or frames < MIN_DISPERSION_FRAMES or not 0.0 < sk < sn:
            return float(max(n, 1))
        rate = sk / sn
        chi2 = (k2n - 2.0 * rate * sk + rate * rate * sn) / (rate * (1.0 - rate))   # Σ (k − n p̂)² / (n p̂ (1 − p̂))
        self.dispersion = max(1.0, chi2 / (frames - 1))
        return self.dispersion

    def _old(self, ids: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """(N,) bool: confirmed before this frame and made before the latest gap."""
        return (np.asarray(counts) >= self.config.confirm_count) & (np.asarray(ids) < self.reference_ids)

    def _accumulate(self, e: FrameEvidence) -> None:
        if e.predicted:
            self.frames_tested += 1
            self.predicted += e.predicted
            self.redetected += e.redetected
            self.expected += e.expected
        before = self.statistic
        self.statistic = max(0.0, before + e.log_ratio)
        if self.statistic > 0.0:
            if before == 0.0 or self._onset is None:
                self._onset = {"since": e.t, "predicted": 0, "redetected": 0, "expected": 0.0, "frames": 0}
            o = self._onset
            o["predicted"] += e.predicted
            o["redetected"] += e.redetected
            o["expected"] += e.expected
            o["frames"] += 1
        else:
            self._onset = None
        if self.statistic > self.max_statistic:
            self.max_statistic, self.max_statistic_t = self.statistic, e.t
        if self.statistic >= self.threshold:
            self.n_alarms += 1
            if len(self.alarms) < MAX_ALARMS:
                o = self._onset
                self.alarms.append({"t": e.t, "since": o["since"], "statistic": round(self.statistic, 3),
                                    "frames": o["frames"], "predicted": o["predicted"],
                                    "redetected": o["redetected"], "expected": round(o["expected"], 2),
                                    "first_id_after_gap": self.reference_ids})
            self.statistic, self._onset = 0.0, None   # restart: a later episode is flagged again
            self._excursion[:] = 0.0                   # out of control: never part of the dispersion
        elif self.statistic == 0.0:
            self._in_control += self._excursion
            self._excursion[:] = 0.0

    @property
    def lost(self) -> bool:
        return self.n_alarms > 0

    def verdict(self) -> dict:
        """The map's ``metadata["self_check"]``: JSON-ready, bounded (MAX_ALARMS alarms)."""
        return {"version": VERSION, "lost": self.lost, "alarms": list(self.alarms), "n_alarms": self.n_alarms,
                "threshold": round(self.threshold, 3), "false_alarm_per_frame": self.config.self_check_false_alarm,
                "dispersion": round(self.dispersion, 3), "statistic": round(self.statistic, 3),
                "max_statistic": round(self.max_statistic, 3),
                "max_statistic_t": self.max_statistic_t, "frames": self.frames, "frames_tested": self.frames_tested,
                "predicted": self.predicted, "redetected": self.redetected, "expected": round(self.expected, 2)}


def slot_view(store, pose: np.ndarray, slots: np.ndarray, well_in_view, sensor_offset) -> tuple[np.ndarray, ...]:
    """(ids, counts, planar ranges, world bearings) of the landmarks in store ``slots`` (K,) that a particle at
    ``pose`` (3,) predicts well in view (``well_in_view(x, y, z)`` on base_link points, the filter's own test),
    seen from the sensor."""
    slots = np.asarray(slots, np.int64)
    mean = store.flat_mean[slots]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = mean[:, 0] - pose[0], mean[:, 1] - pose[1]
    x, y = c * dx + s * dy, c * dy - s * dx
    inside = well_in_view(x, y, mean[:, 2])
    dx, dy = x[inside] - sensor_offset[0], y[inside] - sensor_offset[1]
    bearings = pose[2] + np.arctan2(dy, dx)
    return store.flat_lid[slots[inside]], store.flat_count[slots[inside]], np.hypot(dx, dy), bearings
