"""Namings nothing checks that a map's frame or path rests on (issue 13, MRCLAM without barcodes; session 43 (A)).

Why: :mod:`estimation.frame_reliability` asks which single *sighting* the frame rests on. A wrong naming is not one
sighting's error: it is a run of sightings given the name of a post they are not of, each consistent with its
neighbours, and the map's fit can absorb it by moving whatever the run alone ties to the rest. On MRCLAM robot 1
with a truth-free noise model (session 40 (B)) the chain's first 115 s are joined to the rest of the map only by 7
sightings of post 12's first glimpse (7.98–9.90 s) named as post 13, 1.07 m away, and by 30 s of odometry: the frame
ends 0.9 m off, its covariance says 0.04 m, and no sighting is flagged (session 42 (A2)).

The question asked here, of every run of a name's kept sightings but its largest (:func:`~estimation.map_honesty.
sighting_runs`: a name's visits, cut at gaps of ``gap_s``): what if the run were not of its name? That is the
hypothesis "the run's sightings see their landmark displaced by an unknown δ" (2 dof; δ = 0 is the naming), the
split of :func:`estimation.map_honesty.split_scores`, and Baarda's and Förstner's reliability answers it as for one
sighting, with the run's offset for the sighting's error:

- V = J_δᵀJ_δ − Bᵀ H⁻¹ B (B = J_xᵀJ_δ, H = JᵀJ the smoother's normal matrix, J_δ the landmark's columns on the
  run's rows) is δ's information given everything else the map holds; V⁻¹ its covariance. The run is **untestable**
  (merge_audit's power rule, :func:`estimation.batch_audit.untestable_runs`: the same V, the same verdict) when an
  offset of the nearest distance at which two of the map's landmarks are seen in one frame
  (:func:`~estimation.merge_audit.covisible_spacing`) along δ's widest axis still scores within χ²₂ 99 %: a
  neighbouring post would pass for the name's own. A singular V (the run's offset absorbed exactly by the rest: the
  stretch it ties floats without it) is untestable too; ``untestable_runs`` leaves such runs out (no split score).
- External reliability: an unseen δ moves the solution by −H⁻¹Bδ, the frame (the landmarks' rigid motion about pose
  0, :func:`~estimation.landmark_scores.rigid_functional`, as frame_reliability's) by −Kδ, K = g H⁻¹ B. The largest
  move of frame coordinate a by a δ the data's test finds no more than 80 % of the time (δᵀVδ ≤ δ₀², δ₀ = 4.13, the
  one-sighting test's noncentrality: Baarda's B method) is δ₀ √(K_a V⁻¹ K_aᵀ); against the frame's σ_a that is
  δ₀ √(Δvar_a / var_a), Δvar_a = K_a V⁻¹ K_aᵀ being what freeing δ adds to the frame's variance. So an untestable
  naming moves a coordinate by more than δ₀ σ exactly when without it that coordinate's variance more than doubles:
  the frame rests more on that naming than on everything else. The same per pose (x, y, heading) gives the stretch
  of the path that rests on it, the run's own frames apart: a pose that sees only the run rests on it whatever it
  is named (MRCLAM's default chains: 7 right namings of short runs on robot 2 move their own poses by 4.1-10.0 σ,
  the wrong ones of robots 2 and 5 theirs by 65.5 and 4.7 σ), and what is asked is what the naming *ties*: robot 1's
  island with its truth-free model moves from 50.9 s on, 4074 poses (``own_effect_sd`` keeps the own frames' worst).

Measured (session 43 (A); the chain's final states, seed 0): robot 1 with the truth-free ``self-kd-1`` model (frame
0.9 m off, NEES 667) flagged on its one wrong untestable naming, the 7 sightings of post 12 at 7.98-9.86 s named as
post 13: 19.1 σ of the frame's x, the path from 50.9 s on; the default (in-sample) chains of robots 1, 2, 5 and robot
1's first 400 s: frames ≤ 0.5 σ, one flag, robot 2's 2 right sightings of post 17 at 1826.0-1826.3 s moving
the pose before them (1825.5 s) by 5.2 σ.
- The split itself: δ̂ = −V⁻¹J_δᵀr, the frame's first-order move −Kδ̂ if the run had a name of its own (what the
  data say the naming costs; the warning does not rest on it: an untestable naming's δ̂ is as likely noise).

A naming is **unchecked** (warned) when it is untestable and moves a frame coordinate or a pose by more than δ₀ of its
σ. Design only: no truth, no barcode (a run is named by its time, the chain's name, and by barcode only where a
truth scores the map, as frame_reliability's sightings).

What it is not: a test that the naming is wrong. Robot 1's map rests on its misnamed glimpse whether or not it is
misnamed; what this says is that nothing else could have told, and what it costs the frame if it is.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .frame_reliability import DELTA_0, frame_problem, has_frame
from .landmark_smoother import LandmarkLogProblem, Smoothed, normalised_residuals
from .map_honesty import Run, minor_runs
from .merge_audit import covisible_spacing, indistinguishable

__all__ = ["NamingReliability", "naming_metrics", "naming_reliability", "naming_warning"]

_SOLVE_RUNS = 128          # runs per batch of solves (two right-hand sides each)
_SINGULAR = 1e-9           # V's smallest eigenvalue below this share of tr(J_δᵀJ_δ): the rest absorbs the run


@dataclass(frozen=True)
class NamingReliability:
    """Per candidate run r (R,) (every run of a name's kept sightings but the name's largest): ``runs``; ``untestable``
    (R,) bool; ``offset_sd`` (R,) δ's σ along its widest axis (m; inf where V is singular); ``frame_effect`` (R, 3)
    the most an offset the data's test finds ≤ 80 % of the time moves the frame's (x, y, θ) (m, m, rad; inf where V is
    singular); ``frame_effect_sd`` (R, 3) the same in the frame's σ; ``split_shift`` (R, 3) the frame's first-order
    move were the run given a name of its own (NaN where V is singular); ``path_effect_sd`` {r: (T, 3)} for each
    untestable run r, per pose 1..T the most such an offset moves its (x, y, θ) in the pose's σ, 0 at the run's own
    frames, whose worst is ``own_effect_sd`` (R,) (NaN for a testable run); the
    frame's ``frame_sd`` (3,), ``spacing_m`` (covisible_spacing), ``delta0``."""

    runs: list[Run]
    untestable: np.ndarray
    offset_sd: np.ndarray
    frame_effect: np.ndarray
    frame_effect_sd: np.ndarray
    split_shift: np.ndarray
    path_effect_sd: dict[int, np.ndarray]
    own_effect_sd: np.ndarray
    frame_sd: np.ndarray
    spacing_m: float
    delta0: float

    def unchecked(self) -> np.ndarray:
        """(R,) bool: untestable and moving the frame or some pose by more than δ₀ of its σ."""
        path = np.zeros(len(self.runs))
        for i, effect in self.path_effect_sd.items():
            path[i] = effect.max(initial=0.0)
        frame = np.nan_to_num(self.frame_effect_sd, nan=0.0, posinf=np.inf).max(axis=1, initial=0.0)
        return self.untestable & ((frame > self.delta0) | (path > self.delta0))


def naming_reliability(problem: LandmarkLogProblem, solution: Smoothed, *, gap_s: float = 5.0, alpha: float = 0.01,
                       delta0: float = DELTA_0) -> NamingReliability:
    """The figures of the module docstring for every candidate run of ``solution`` (one factorisation of H; two
    solves per run). Needs two landmarks with a kept sighting (a frame)."""
    if not 0 < alpha < 1:
        raise ValueError(f"need 0 < α < 1, not {alpha}")
    t = problem.n_poses
    frame = frame_problem(problem, solution)
    inverse, width, functional = frame.inverse, frame.width, frame.functional
    jac = inverse.jac
    column = np.cumsum(frame.free) - 1
    frame_sd = np.sqrt(np.diag(frame.covariance))
    pose_cols = (width * np.arange(t)[:, None] + np.arange(3)).ravel()
    pose_var = inverse.entries(pose_cols, pose_cols).reshape(t, 3)
    spacing = covisible_spacing(problem, solution)
    runs = minor_runs(problem, solution, gap_s)
    count = len(runs)
    untestable = np.zeros(count, bool)
    offset_sd = np.full(count, np.nan)
    effect = np.full((count, 3), np.nan)
    shift = np.full((count, 3), np.nan)
    path: dict[int, np.ndarray] = {}
    own_worst = np.full(count, np.nan)
    _, residuals, _ = normalised_residuals(problem, solution)
    base = 3 * t                                             # the sightings' rows follow the odometry's 3T
    for start in range(0, count, _SOLVE_RUNS):
        chunk = range(start, min(start + _SOLVE_RUNS, count))
        cross, own, grad = [], [], []
        for i in chunk:
            run = runs[i]
            rows = (base + 2 * run.sightings[:, None] + np.arange(2)).ravel()
            block = jac[rows]
            j_delta = block[:, column[width * t + 2 * run.landmark + np.arange(2)]].toarray()
            cross.append(sp.csc_matrix(block.T @ j_delta))                  # B = J_xᵀ J_δ
            own.append(j_delta.T @ j_delta)
            grad.append(j_delta.T @ residuals[run.sightings].ravel())
        rhs = sp.hstack(cross).toarray()
        solved = inverse.factor.solve(rhs)                                  # H⁻¹ B
        for k, i in enumerate(chunk):
            w = solved[:, 2 * k:2 * k + 2]
            v = own[k] - rhs[:, 2 * k:2 * k + 2].T @ w
            v = 0.5 * (v + v.T)
            gain = functional @ w                                           # K (3, 2)
            eig = np.linalg.eigvalsh(v)
            if eig[0] <= _SINGULAR * max(np.trace(own[k]), 1e-300):
                untestable[i] = True
                offset_sd[i] = np.inf
                moves = np.abs(gain).max(axis=1) > 1e-9 * np.maximum(frame_sd, 1e-300)
                effect[i] = np.where(moves, np.inf, 0.0)
                pose_gain = np.abs(w[:t * width].reshape(t, width, 2)[:, :3]).max(axis=2)
                path[i] = np.where(pose_gain > 1e-9 * np.sqrt(np.maximum(pose_var, 1e-300)), np.inf, 0.0)
                continue
            cov = np.linalg.inv(v)
            offset_sd[i] = float(np.sqrt(1.0 / eig[0]))                   # V⁻¹'s widest σ
            untestable[i] = indistinguishable(offset_sd[i], spacing, alpha)
            effect[i] = delta0 * np.sqrt(np.einsum("ai,ij,aj->a", gain, cov, gain))
            shift[i] = gain @ (cov @ grad[k])                               # −K δ̂, δ̂ = −V⁻¹ J_δᵀ r
            if untestable[i]:
                pose_w = w[:t * width].reshape(t, width, 2)[:, :3]          # (T, 3, 2)
                added = np.einsum("tai,ij,taj->ta", pose_w, cov, pose_w)
                with np.errstate(divide="ignore", invalid="ignore"):
                    path[i] = delta0 * np.sqrt(np.where(added > 0, added / pose_var, 0.0))
    for i, moved in path.items():                           # the run's own frames apart (module docstring)
        own_frames = np.unique(problem.pose_index[runs[i].sightings]) - 1
        own_worst[i] = float(moved[own_frames].max())
        moved[own_frames] = 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        effect_sd = np.where(effect == 0, 0.0, effect / frame_sd)
    return NamingReliability(runs, untestable, offset_sd, effect, effect_sd, shift, path, own_worst, frame_sd,
                             float(spacing), float(delta0))


def naming_metrics(problem: LandmarkLogProblem, solution: Smoothed, times: np.ndarray, names: np.ndarray, *,
                   barcodes: np.ndarray | None = None, gap_s: float = 5.0) -> dict:
    """The figures a chain's run reports (``times`` (T,) each pose's log time, pose k at times[k − 1]; ``names`` (L,)
    each landmark index's name; ``barcodes`` (S,), if given, each sighting's barcode: only where a truth scores the
    map, then each naming says the barcodes its run carries), from the design alone:

    - ``untestable_naming_runs``: how many runs of a name's sightings the map cannot test against the rest of their
      name (module docstring), of ``naming_runs`` candidate runs; ``naming_reliability_spacing_m`` the spacing used;
    - ``untestable_namings``: those of them that move the frame or a stretch of the path by more than δ₀ of its σ,
      worst first: the name, the run's first and last time and sightings, δ's widest σ, the frame's largest
      unseen move (m, m, rad; null: unbounded) and in σ, the frame's move were the run its own name, and the stretch
      of the path moved beyond δ₀ σ (first and last pose times, poses, the worst pose's effect in σ);
    - ``naming_reliability_unchecked``: whether there is one (:func:`naming_warning` says it).

    {} when there is no frame (fewer than two landmarks with a kept sighting); any other error of the figures
    propagates."""
    if not has_frame(problem, solution):
        return {}
    rel = naming_reliability(problem, solution, gap_s=gap_s)
    flagged = np.flatnonzero(rel.unchecked())
    with np.errstate(invalid="ignore"):
        worst = np.nan_to_num(rel.frame_effect_sd, nan=0.0).max(axis=1)
    flagged = flagged[np.argsort(-worst[flagged], kind="stable")]
    times = np.asarray(times, float)

    def finite(values) -> list:
        return [float(v) if np.isfinite(v) else None for v in values]

    out = []
    for i in flagged:
        run = rel.runs[i]
        moved = rel.path_effect_sd[i].max(axis=1) > rel.delta0
        poses = np.flatnonzero(moved)
        stretch = ({"start_s": float(times[poses[0]]), "end_s": float(times[poses[-1]]), "poses": int(len(poses)),
                    "worst_sd": finite([rel.path_effect_sd[i][poses].max()])[0]} if len(poses) else None)
        sighted = times[problem.pose_index[run.sightings] - 1]
        entry = {"name": int(names[run.landmark]), "start_s": float(sighted.min()), "end_s": float(sighted.max()),
                 "sightings": int(len(run.sightings)), "offset_sd_m": finite([rel.offset_sd[i]])[0],
                 "own_poses_effect_sd": finite([rel.own_effect_sd[i]])[0],
                 "frame_effect": finite(rel.frame_effect[i]), "frame_effect_sd": finite(rel.frame_effect_sd[i]),
                 "split_frame_shift": finite(rel.split_shift[i]), "path": stretch}
        if barcodes is not None:
            codes, counts = np.unique(np.asarray(barcodes)[run.sightings], return_counts=True)
            entry["barcodes"] = {str(int(c)): int(m) for c, m in zip(codes, counts, strict=True)}
        out.append(entry)
    return {"naming_runs": len(rel.runs), "untestable_naming_runs": int(rel.untestable.sum()),
            "naming_reliability_spacing_m": rel.spacing_m if np.isfinite(rel.spacing_m) else None,
            "naming_reliability_frame_sd": [float(v) for v in rel.frame_sd],
            "untestable_namings": out, "naming_reliability_unchecked": bool(out)}


def naming_warning(metrics: dict) -> str | None:
    """One line when ``metrics`` (:func:`naming_metrics`'s) hold an unchecked naming: the worst one (by its effect
    on the frame), what it ties, and how many more there are. None otherwise (or without the figures)."""
    namings = metrics.get("untestable_namings") or []
    if not namings:
        return None
    n = namings[0]
    sd = [np.inf if v is None else v for v in n["frame_effect_sd"]]
    axis = int(np.argmax(sd))
    parts = []
    if sd[axis] > DELTA_0:
        unit = "rad" if axis == 2 else "m"
        size = "without bound" if n["frame_effect"][axis] is None else f"by {n['frame_effect'][axis]:.3g} {unit}"
        parts.append(f"the frame's {('x', 'y', 'heading')[axis]} can move {size} "
                     + ("(nothing else holds it)" if np.isinf(sd[axis]) else f"({sd[axis]:.1f} σ)"))
    if n["path"] is not None:
        p = n["path"]
        worst = "can move without bound" if p["worst_sd"] is None else f"can move up to {p['worst_sd']:.1f} σ"
        parts.append(f"the pose at {p['start_s']:.1f} s {worst}" if p["poses"] == 1 else
                     f"the path from {p['start_s']:.1f} s to {p['end_s']:.1f} s ({p['poses']} poses) {worst}")
    codes = "" if "barcodes" not in n else " (barcodes " + ", ".join(
        f"{c}: {m}" for c, m in n["barcodes"].items()) + ")"
    more = len(namings) - 1
    run = (f"sighting at {n['start_s']:.2f} s" if n["sightings"] == 1 else
           f"{n['sightings']} sightings at {n['start_s']:.2f}–{n['end_s']:.2f} s")
    return (f"the map rests on a naming nothing checks: name {n['name']}'s {run}{codes} cannot be told from a post "
            f"{metrics['naming_reliability_spacing_m']:.2f} m away (the map's nearest two seen together), and were "
            f"{'it' if n['sightings'] == 1 else 'they'} of another, " + " and ".join(parts)
            + f" unseen by any test (δ₀ {DELTA_0:g})"
            + (f"; {more} more such namings" if more else ""))
