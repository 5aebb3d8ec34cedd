"""Two robots cannot be in one place at one time: a co-location test of a candidate alignment.

Each map carries its robot's trajectory (``LandmarkMap.trajectory``, rows t, x, y, θ in the map's frame).  An
alignment (tx, ty, θ) of map 2's frame in map 1's places robot 2's trajectory in map 1's frame; if at some time
both robots were known to be somewhere, the alignment says where each was.  Two bodies that do not overlap have
centres at least r_a + r_b apart, r the radius of the disc *inscribed* in each footprint (the footprint holds the
disc, so footprints apart means discs apart; a P3-AT is 626 × 505 mm: 0.2525 m).  An alignment that puts the
centres closer, beyond what the uncertainties allow, puts two robots in one place at one time: it is wrong.

The test is statistical.  At each common time t the separation Δ = p₁(t) − (R p₂(t) + t_T) has covariance

    C(t) = σ₁²(t) I + σ₂²(t) I + J(t) Σ_T J(t)ᵀ,     J = ∂(R p₂ + t_T)/∂(tx, ty, θ) = [I | R' p₂]

with Σ_T the alignment's covariance against the true start frames (``Alignment.start_covariance``: the prior's
choice too, since the trajectories are each about their own true start) and σ²(t) a bound on each trajectory's
error against its start frame: its dead reckoning's growth under the map's own noise model
(``metadata["fastslam"]``), per axis σ² ≤ q_xy s + σ_θ²(t) s² with σ_θ²(t) = q_θ/rad a + q_θ/m s (s the path
length, a the angle turned so far; the heading's error acts on at most the whole path as a lever, Minkowski's
bound for errors that move together).  A SLAM trajectory is better than its dead reckoning; near t = 0 the bound is
~0.  d²(t) is the Mahalanobis distance under C(t) from Δ to the nearest separation the bodies allow (a point at
|x| = r_a + r_b; 0 when |Δ| is already that far): the least d² the truth could have.  The alignment fails when
max_t d²(t) exceeds χ²₂ at ``level`` Bonferroni-corrected over the T common times (χ²₂ ≥ d² for a true alignment
at each time; ~26 at 99.9 % over 500 times).

When it is valid: both maps' trajectories on one clock (``metadata["clock"]``: equal names), each map's footprint
known (``metadata["footprint_radius_m"]``) and its noise model kept, neither map flagged lost by its self-check (the
trajectory after the alarm need not be in the frame of the landmarks before it, and a split map's parts keep all of
it), and an alignment covariance.  Otherwise there is no test, and :func:`colocation_test` says why.  Times are
robot 1's trajectory rows inside both spans; robot 2 is interpolated between its rows when they are at most
``MAX_GAP`` s apart, half the chord added to its σ.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from estimation import chi2
from estimation.landmark_map import LandmarkMap
from estimation.map_validation import CLOCK_KEY, FOOTPRINT_KEY, colocation_metadata

from .errors import IncompatibleMapsError

COLOCATION_LEVEL = 0.999      # a true alignment fails the test at most 1 time in 1000 (all times together)
MAX_GAP = 0.5                 # s: robot 2 is interpolated only between rows this close in time
_VARIANCE_FLOOR = 1e-6        # m² (1 mm): keeps C(t) invertible at t = 0 with no other term


def _noise(landmark_map: LandmarkMap) -> tuple[float, float, float, float] | None:
    """(q_xy per m, q_θ per rad, q_θ per m, floor) from the map's own noise model, or None."""
    raw = landmark_map.metadata.get("fastslam")
    try:
        cfg = json.loads(raw) if isinstance(raw, str) else raw
        values = tuple(float(cfg[k]) for k in ("odom_xy_var_per_m", "odom_theta_var_per_rad", "odom_theta_var_per_m"))
        floor = float(cfg.get("odom_var_floor", 0.0))
    except (TypeError, KeyError, ValueError, AttributeError):
        return None
    if not all(np.isfinite(v) and v >= 0 for v in (*values, floor)):
        return None
    return (*values, floor)


def dead_reckoning_variance(trajectory: np.ndarray, noise: tuple[float, float, float, float]) -> np.ndarray:
    """Per-axis position variance bound (T,) of each trajectory row against the start frame (module docstring)."""
    xy_m, th_rad, th_m, floor = noise
    step = np.hypot(*np.diff(trajectory[:, 1:3], axis=0).T)
    turn = np.abs(np.angle(np.exp(1j * np.diff(trajectory[:, 3]))))
    s = np.concatenate([[0.0], np.cumsum(step)])
    a = np.concatenate([[0.0], np.cumsum(turn)])
    heading = th_rad * a + th_m * s + floor
    return xy_m * s + heading * s * s + floor


@dataclass(frozen=True)
class CoLocation:
    """The two robots' positions at their common times, each in its own map's frame, with variance bounds.

    times (T,); p1, p2 (T, 2); var1, var2 (T,) per-axis variances; needed: r_a + r_b (m); names for the reason."""

    times: np.ndarray
    p1: np.ndarray
    p2: np.ndarray
    var1: np.ndarray
    var2: np.ndarray
    needed: float
    robot1: str = "robot1"
    robot2: str = "robot2"
    level: float = COLOCATION_LEVEL

    @property
    def bound(self) -> float:
        """χ²₂ at ``level``, Bonferroni over the common times: the largest d² of an admissible alignment."""
        return float(chi2.isf((1.0 - self.level) / max(len(self.times), 1), 2))

    def d2(self, poses, covariance) -> tuple[np.ndarray, np.ndarray]:
        """For each pose (H, 3) (or one (3,)): max over the common times of d² (H,) and the row where it is reached
        (H,) (−1: none closer than ``needed``).  ``covariance`` (3, 3): the alignment's, against the start frames."""
        poses = np.asarray(poses, float).reshape(-1, 3)
        cov = np.asarray(covariance, float).reshape(3, 3)
        worst = np.zeros(len(poses))
        where = np.full(len(poses), -1, np.int64)
        chunk = max(1, 2_000_000 // max(len(self.times), 1))
        for start in range(0, len(poses), chunk):
            sl = slice(start, start + chunk)
            worst[sl], where[sl] = self._d2_chunk(poses[sl], cov)
        return worst, where

    def _d2_chunk(self, poses: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
        qx = c * self.p2[None, :, 0] - s * self.p2[None, :, 1]               # R p2 (H, T)
        qy = s * self.p2[None, :, 0] + c * self.p2[None, :, 1]
        dx = self.p1[None, :, 0] - (qx + poses[:, 0:1])
        dy = self.p1[None, :, 1] - (qy + poses[:, 1:2])
        h, k = np.nonzero(dx * dx + dy * dy < self.needed ** 2)
        worst = np.zeros(len(poses))
        where = np.full(len(poses), -1, np.int64)
        if len(h) == 0:
            return worst, where
        J = np.zeros((len(h), 2, 3))
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        J[:, 0, 2], J[:, 1, 2] = -qy[h, k], qx[h, k]
        C = J @ cov @ J.transpose(0, 2, 1)
        C += ((self.var1[k] + self.var2[k] + _VARIANCE_FLOOR)[:, None, None] * np.eye(2))
        d2 = exclusion_d2(np.column_stack([dx[h, k], dy[h, k]]), C, self.needed)
        order = np.lexsort((-d2, h))                                           # per hypothesis, largest first
        first = order[np.unique(h[order], return_index=True)[1]]
        worst[h[first]], where[h[first]] = d2[first], k[first]
        return worst, where

    def admits(self, poses, covariance) -> np.ndarray:
        """(H,) bool: whether each pose keeps the two bodies apart at every common time, within :attr:`bound`."""
        return self.d2(poses, covariance)[0] <= self.bound

    def reason(self, pose, covariance) -> str:
        """Why ``pose`` fails the test, in one clause ('' when it passes)."""
        d2, where = self.d2(pose, covariance)
        if d2[0] <= self.bound or where[0] < 0:
            return ""
        k = int(where[0])
        pose = np.asarray(pose, float).reshape(3)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        q = np.array([c * self.p2[k, 0] - s * self.p2[k, 1], s * self.p2[k, 0] + c * self.p2[k, 1]]) + pose[:2]
        gap = float(np.hypot(*(self.p1[k] - q)))
        return (f"{self.robot2} would overlap {self.robot1} at t={self.times[k]:.1f} s: centres {gap:.2f} m apart, "
                f"at least {self.needed:.3f} m needed, d²={d2[0]:.1f} > {self.bound:.1f} (χ²₂ at "
                f"{100 * self.level:g} % over {len(self.times)} common times)")

    def text(self) -> str:
        return (f"co-location tested at {len(self.times)} common times ({self.times[0]:.1f}-{self.times[-1]:.1f} s), "
                f"bodies at least {self.needed:.3f} m apart")


def exclusion_d2(delta: np.ndarray, C: np.ndarray, radius: float) -> np.ndarray:
    """min over |x| ≥ radius of (delta − x)ᵀ C⁻¹ (delta − x), for delta (N, 2) and C (N, 2, 2) positive definite.

    0 where |delta| ≥ radius.  Inside, the minimum lies on the circle: x_i = w_i δ_i / (w_i − μ) in C's eigenbasis
    (w = 1/eigenvalues), μ ∈ [0, w_min) the root of Σ x_i² = radius² (monotone there; found by bisection), which
    the Lagrangian's Hessian 2 (W − μ I) ≻ 0 makes the global minimum."""
    delta = np.asarray(delta, float).reshape(-1, 2)
    out = np.zeros(len(delta))
    inside = np.einsum("ni,ni->n", delta, delta) < radius ** 2
    if not inside.any():
        return out
    evals, U = np.linalg.eigh(np.asarray(C, float).reshape(-1, 2, 2)[inside])
    w = 1.0 / np.maximum(evals, 1e-300)                                       # ascending eigenvalues -> w descending
    d = np.einsum("nji,nj->ni", U, delta[inside])
    tiny = 1e-9 * radius
    d = np.where(np.abs(d) < tiny, np.where(d < 0, -tiny, tiny), d)           # no exactly-zero component
    lo, hi = np.zeros(len(d)), w.min(axis=1)
    for _ in range(100):
        mu = 0.5 * (lo + hi)
        x = w * d / (w - mu[:, None])
        big = np.einsum("ni,ni->n", x, x) > radius ** 2
        hi, lo = np.where(big, mu, hi), np.where(big, lo, mu)
    x = w * d / (w - lo[:, None])                                             # converged: onto the circle
    x *= radius / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-300)
    out[inside] = np.einsum("ni,ni->n", w * (x - d), x - d)
    return out


def colocation_test(map1: LandmarkMap, map2: LandmarkMap, level: float = COLOCATION_LEVEL
                    ) -> tuple[CoLocation | None, str]:
    """The co-location test of two maps, or (None, why there is none).  Raises :class:`IncompatibleMapsError` with
    one line when a map's clock or footprint is a hostile value."""
    fields = []
    for m in (map1, map2):
        try:
            fields.append(colocation_metadata(m.metadata))
        except ValueError as exc:
            raise IncompatibleMapsError(f"map of {m.robot}: {exc}") from None
    (clock1, r1), (clock2, r2) = fields
    for m, clock, r in ((map1, clock1, r1), (map2, clock2, r2)):
        if clock is None:
            return None, f"the map of {m.robot} does not name its trajectory's clock (metadata '{CLOCK_KEY}')"
        if r is None:
            return None, f"the map of {m.robot} does not give its robot's footprint (metadata '{FOOTPRINT_KEY}')"
    if clock1 != clock2:
        return None, f"the maps' trajectories are on different clocks ({clock1!r}, {clock2!r})"
    for m in (map1, map2):
        verdict = m.metadata.get("self_check")
        if isinstance(verdict, dict) and verdict.get("lost"):
            return None, (f"the map of {m.robot} flagged itself as lost (self-check): its trajectory after the alarm "
                          f"need not share the frame of its landmarks before it (a part of a split map keeps it all)")
    noise = [_noise(m) for m in (map1, map2)]
    for m, n in zip((map1, map2), noise, strict=True):
        if n is None:
            return None, f"the map of {m.robot} keeps no noise model to bound its trajectory's error"
    t1, t2 = map1.trajectory, map2.trajectory
    if len(t1) < 1 or len(t2) < 2:
        return None, "a map holds no trajectory"
    if np.any(np.diff(t1[:, 0]) < 0) or np.any(np.diff(t2[:, 0]) < 0):
        return None, "a map's trajectory goes back in time"
    var1 = dead_reckoning_variance(t1, noise[0])
    var2 = dead_reckoning_variance(t2, noise[1])
    times = t1[:, 0]
    after = np.searchsorted(t2[:, 0], times, side="left")
    exact = (after < len(t2)) & (t2[np.minimum(after, len(t2) - 1), 0] == times)
    b = np.clip(after, 1, len(t2) - 1)
    a = b - 1
    span = t2[b, 0] - t2[a, 0]
    bracketed = (times >= t2[a, 0]) & (times <= t2[b, 0]) & (span <= MAX_GAP)
    keep = exact | bracketed
    if not keep.any():
        return None, f"the trajectories share no time (robot 2's rows at most {MAX_GAP:g} s apart)"
    a, b, span, times, exact = a[keep], b[keep], span[keep], times[keep], exact[keep]
    f = np.where(span > 0, (times - t2[a, 0]) / np.where(span > 0, span, 1.0), 0.0)
    p2 = (1 - f)[:, None] * t2[a, 1:3] + f[:, None] * t2[b, 1:3]
    chord = np.hypot(*(t2[b, 1:3] - t2[a, 1:3]).T)
    v2 = np.maximum(var2[a], var2[b]) + np.where(exact, 0.0, (0.5 * chord) ** 2)
    return CoLocation(times, t1[keep, 1:3], p2, var1[keep], v2, float(r1 + r2), map1.robot, map2.robot, level), ""
