"""A rough prior on the robots' relative start: where map 2's frame lies in map 1's, roughly.

Real fleets usually know roughly where their robots started (one docking area, a tape mark, a rendezvous), and
MRPT/ROS map mergers take an initial guess.  The alignment's evidence alone cannot tell a building's half turn from
the truth when both look alike (docs/fusion-history.md, "Rendered demo: is the half-turn symmetry real in appearance?");
a prior can, and :func:`fusion.align` uses it only to *remove* hypotheses, never to add support:

* a hypothesis is consistent with the prior when χ² = dᵀ (C_prior + C) ⁻¹ d is within χ²₃ at ``level`` (99.9 %:
  16.27), d the difference of the poses (tx, ty, θ wrapped) and C the estimate's covariance against the true start
  frames (``Alignment.start_covariance``), since the prior is about the true starts, not the maps' frames;
* a rival outside the prior is not a rival; the best alignment by the evidence outside it is "not found: the maps'
  best alignment contradicts the prior", never the best of the hypotheses inside it;
* the Bonferroni factor of the evidence counts only the hypotheses tried inside the prior (a false alarm needs the
  best hypothesis to be inside it, and there are fewer chances there).

Convention: the same as ``Alignment.pose``: (tx, ty, θ) of map 2's frame (robot 2's start) in map 1's frame,
REP-103, metres and radians, θ counter-clockwise.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from estimation import chi2
from estimation.fileio import read_bounded
from estimation.geometry import wrap_angle

from .errors import IncompatibleMapsError
from .pose_covariance import compose_with_covariance, inverse_with_covariance

# A hypothesis outside the prior's 99.9 % region (χ²₃) is not a candidate: a true start lands outside it 1 time in 1000.
PRIOR_LEVEL = 0.999


@dataclass(frozen=True)
class StartPrior:
    """A Gaussian prior on the pose (tx, ty, θ) of map 2's frame in map 1's: ``mean`` (3,), ``covariance`` (3, 3)."""

    mean: np.ndarray
    covariance: np.ndarray
    level: float = PRIOR_LEVEL
    source: str = field(default="given", compare=False)   # where it came from, for reports

    def __post_init__(self) -> None:
        mean = np.asarray(self.mean, float).reshape(-1)
        cov = np.asarray(self.covariance, float)
        if mean.shape != (3,) or not np.all(np.isfinite(mean)):
            raise IncompatibleMapsError(f"a start prior's mean is (tx, ty, θ), three finite numbers; got {self.mean!r}")
        if cov.shape != (3, 3) or not np.all(np.isfinite(cov)) or not np.allclose(cov, cov.T) \
                or np.linalg.eigvalsh(cov).min() <= 0:
            raise IncompatibleMapsError("a start prior's covariance must be a symmetric positive definite 3×3 matrix")
        if not 0.0 < self.level < 1.0:
            raise IncompatibleMapsError(f"a start prior's level is a probability in (0, 1); got {self.level}")
        object.__setattr__(self, "mean", np.array([mean[0], mean[1], wrap_angle(mean[2])]))
        object.__setattr__(self, "covariance", 0.5 * (cov + cov.T))

    @classmethod
    def from_sigmas(cls, mean, sigma_xy: float, sigma_theta: float, source: str = "given") -> StartPrior:
        """Independent errors: σ in metres on tx and ty, σ in radians on θ."""
        _check_sigmas(sigma_xy, sigma_theta)
        return cls(np.asarray(mean, float), np.diag([sigma_xy ** 2, sigma_xy ** 2, sigma_theta ** 2]), source=source)

    @classmethod
    def between_starts(cls, start1, start2, sigma_xy: float, sigma_theta: float, source: str = "start poses"
                       ) -> StartPrior:
        """The prior from each robot's start pose (x, y, yaw) in a common frame, each known to within σ (metres,
        radians) independently: mean between(start1, start2), covariance propagated through it."""
        _check_sigmas(sigma_xy, sigma_theta)
        return cls(*_relative(start1, (sigma_xy, sigma_theta), start2, (sigma_xy, sigma_theta)), source=source)

    def inverse(self) -> StartPrior:
        """The prior on map 1's frame in map 2's (for the pair aligned the other way round)."""
        pose, cov = inverse_with_covariance(self.mean, self.covariance)
        return StartPrior(pose, cov, self.level, self.source)

    @property
    def bound(self) -> float:
        """χ²₃ at ``level``: the largest χ² of a consistent hypothesis."""
        return float(chi2.ppf(self.level, 3))

    def chi2(self, poses, covariance=None) -> np.ndarray:
        """χ² of each pose (H, 3) (or one (3,)) against the prior, with ``covariance`` (3, 3) the estimate's own
        uncertainty against the true start frames added to the prior's (None: the prior's alone)."""
        p = np.asarray(poses, float)
        one = p.ndim == 1
        p = p.reshape(-1, 3)
        d = p - self.mean
        d[:, 2] = wrap_angle(d[:, 2])
        s = self.covariance + (0.0 if covariance is None else np.asarray(covariance, float).reshape(3, 3))
        out = np.einsum("hi,hi->h", d, np.linalg.solve(s, d.T).T)
        return out[0] if one else out

    def admits(self, poses, covariance=None) -> np.ndarray:
        """Whether each pose is consistent with the prior (χ² within :attr:`bound`)."""
        return self.chi2(poses, covariance) <= self.bound

    def offset(self, pose) -> tuple[float, float]:
        """(distance (m), |Δθ| (rad)) of a pose from the prior's mean."""
        d = np.asarray(pose, float).reshape(3) - self.mean
        return float(np.hypot(d[0], d[1])), float(abs(wrap_angle(d[2])))

    def sigmas(self) -> tuple[float, float]:
        """(σ xy (m): the root of the larger eigenvalue of the xy block, σ θ (rad))."""
        return (float(np.sqrt(np.linalg.eigvalsh(self.covariance[:2, :2]).max())),
                float(np.sqrt(self.covariance[2, 2])))

    def text(self) -> str:
        sxy, sth = self.sigmas()
        tx, ty, th = self.mean
        return (f"prior ({self.source}): tx={tx:+.2f} m ty={ty:+.2f} m θ={th:+.3f} rad, 1σ {sxy:.2f} m / "
                f"{sth:.3f} rad, consistent within χ²₃ {self.bound:.1f} ({100 * self.level:g} %)")

    def to_dict(self) -> dict:
        return {"mean": [float(v) for v in self.mean], "covariance": self.covariance.tolist(),
                "level": self.level, "source": self.source}


def _relative(start1, sigmas1, start2, sigmas2) -> tuple[np.ndarray, np.ndarray]:
    """between(start1, start2) (mean) and its covariance, each start's error independent (σ xy, σ θ)."""
    c1, c2 = (np.diag([sxy ** 2, sxy ** 2, sth ** 2]) for sxy, sth in (sigmas1, sigmas2))
    inv1, cov_inv1 = inverse_with_covariance(np.asarray(start1, float).reshape(3), c1)
    return compose_with_covariance(inv1, cov_inv1, np.asarray(start2, float).reshape(3), c2)


# a start pose and its standard deviations are a lab's rough guess: beyond these they are corrupt (1e300 overflowed
# the relative pose's covariance: RuntimeWarnings, or OverflowError and exit 70 for σ = 1e300)
MAX_START_COORDINATE = 1e6   # m, as a map's coordinates (estimation.map_validation.MAX_COORDINATE)
MAX_START_YAW = 1e3          # rad
MAX_START_SIGMA = 1e6        # m or rad


def _check_sigmas(sigma_xy: float, sigma_theta: float) -> None:
    if not (np.isfinite(sigma_xy) and np.isfinite(sigma_theta) and sigma_xy > 0 and sigma_theta > 0):
        raise IncompatibleMapsError(f"a start prior's standard deviations must be positive and finite; got "
                                    f"{sigma_xy} m, {sigma_theta} rad")
    if max(sigma_xy, sigma_theta) > MAX_START_SIGMA:
        raise IncompatibleMapsError(f"a start prior's standard deviations must be at most {MAX_START_SIGMA:g}; got "
                                    f"{sigma_xy:g} m, {sigma_theta:g} rad")


def _check_pose(pose) -> None:
    x, y, yaw = (float(v) for v in np.asarray(pose, float).reshape(3))
    if not (max(abs(x), abs(y)) <= MAX_START_COORDINATE and abs(yaw) <= MAX_START_YAW):
        raise IncompatibleMapsError(f"a start pose must lie within {MAX_START_COORDINATE:g} m and {MAX_START_YAW:g} "
                                    f"rad; got {x:g}, {y:g}, {yaw:g}")


def parse_start(text: str) -> tuple[np.ndarray, tuple[float, float] | None]:
    """'x,y,yaw' or 'x,y,yaw,sigma_xy,sigma_yaw' (metres, radians) -> (pose (3,), sigmas or None); one-line errors."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise IncompatibleMapsError("a start pose is x,y,yaw[,sigma_xy,sigma_yaw] in metres and radians; got "
                                    f"{text[:80]!r}") from None
    if len(values) not in (3, 5) or not np.all(np.isfinite(values)):
        raise IncompatibleMapsError(f"a start pose is x,y,yaw[,sigma_xy,sigma_yaw] (3 or 5 finite numbers); "
                                    f"got {text[:80]!r}")
    sig = None if len(values) == 3 else (values[3], values[4])
    if sig is not None:
        _check_sigmas(*sig)
    _check_pose(values[:3])
    return np.array(values[:3]), sig


def pair_priors(starts: dict[int, tuple[np.ndarray, tuple[float, float]]], n: int, source: str = "start poses"
                ) -> dict[tuple[int, int], StartPrior]:
    """Priors for every pair (i, j), i < j, of maps whose start poses are known: {index: (pose, (σ xy, σ θ))}."""
    for k in starts:
        if not 0 <= k < n:
            raise IncompatibleMapsError(f"a start pose names map {k}, but there are {n} maps (0..{n - 1})")
    return named_pair_priors(starts, source)


def named_pair_priors(starts: dict, source: str = "start poses") -> dict[tuple, StartPrior]:
    """Priors for every pair (a, b), a < b, of the keys whose start poses are known: {key: (pose, (σ xy, σ θ))}.
    Keys are map indices (``p3at fuse``) or robot names (the live fusions, whose maps come and go by robot)."""
    for pose, sigmas in starts.values():   # also those given apart from parse_start (a --start-sigma, the API)
        _check_pose(pose)
        _check_sigmas(*sigmas)
    return {(a, b): StartPrior(*_relative(*starts[a], *starts[b]), source=source)
            for a in sorted(starts) for b in sorted(starts) if a < b}


MAX_START_FILE_BYTES = 1 << 20   # a start-pose file holds a few poses: refuse anything absurd before parsing


def load_starts(path: str) -> dict[str, tuple[np.ndarray, tuple[float, float] | None]]:
    """A JSON file {"sigma_xy": m, "sigma_yaw": rad, "starts": {"<robot or index>": [x, y, yaw] or
    [x, y, yaw, sigma_xy, sigma_yaw]}} -> {key: (pose, sigmas)}; one-line errors."""
    try:
        data = json.loads(read_bounded(path, MAX_START_FILE_BYTES).decode("utf-8"),   # never waits on a FIFO
                          object_pairs_hook=_unique_keys)
        starts = data["starts"]
        items = starts.items()
    except OSError as e:
        raise IncompatibleMapsError(f"{path}: cannot read the start-pose file ({e.strerror or e})") from None
    except (ValueError, KeyError, TypeError, AttributeError, OverflowError, RecursionError) as e:
        why = "nested too deeply" if isinstance(e, RecursionError) else str(e)[:200]
        raise IncompatibleMapsError(f"{path}: not a start-pose file ({{\"starts\": {{name: [x, y, yaw]}}, "
                                    f"\"sigma_xy\": m, \"sigma_yaw\": rad}}): {why}") from None
    default = _file_sigmas(path, data)
    out = {}
    for key, value in items:
        numbers = isinstance(value, list) and all(isinstance(v, int | float) and not isinstance(v, bool)
                                                  for v in value)
        if not (numbers or isinstance(value, str)):   # a string "x,y,yaw" as --start-pose takes it
            raise IncompatibleMapsError(f"{path}: starts.{str(key)[:40]} must be [x, y, yaw] or [x, y, yaw, "
                                        f"sigma_xy, sigma_yaw] (numbers); got {json.dumps(value)[:60]}")
        try:
            pose, sig = parse_start(",".join(repr(float(v)) for v in value) if numbers else value)
        except OverflowError:  # float() of an integer of hundreds of digits
            raise IncompatibleMapsError(f"{path}: starts.{str(key)[:40]} holds a number out of range") from None
        except IncompatibleMapsError as e:
            raise IncompatibleMapsError(f"{path}: starts.{str(key)[:40]}: {e}") from None
        if sig is None:
            sig = default
        out[str(key)] = (pose, sig)             # None: the caller's default σ
    return out


_START_FILE_KEYS = ("starts", "sigma_xy", "sigma_yaw")


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    """A JSON object's pairs as a dict; a key given twice is an error (json keeps the last one in silence)."""
    out = dict(pairs)
    if len(out) < len(pairs):
        seen: set[str] = set()
        twice = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise ValueError(f"key {str(twice)[:40]!r} appears twice")
    return out


def _file_sigmas(path: str, data: dict) -> tuple[float, float] | None:
    """The start-pose file's own default σ (sigma_xy, sigma_yaw), None if it gives none; a key this format does not
    have, or a σ that is not a positive finite number, or one without the other, is an error (they were ignored:
    ``"sigma_xy": NaN`` read as no σ, ``true`` as 1 m, a misspelt key was dropped in silence)."""
    unknown = sorted(str(k)[:40] for k in data if k not in _START_FILE_KEYS)
    if unknown:
        raise IncompatibleMapsError(f"{path}: unknown key(s) {', '.join(unknown)} (a start-pose file has "
                                    f"{', '.join(_START_FILE_KEYS)})")
    given = [k for k in ("sigma_xy", "sigma_yaw") if k in data]
    if not given:
        return None
    if len(given) == 1:
        raise IncompatibleMapsError(f"{path}: {given[0]} without {({'sigma_xy', 'sigma_yaw'} - set(given)).pop()}: "
                                    "give both or neither")
    values = []
    for key in given:
        value = data[key]
        number = isinstance(value, int | float) and not isinstance(value, bool)
        try:
            ok = number and np.isfinite(float(value)) and float(value) > 0
        except OverflowError:   # an integer of hundreds of digits
            ok = False
        if not ok:
            raise IncompatibleMapsError(f"{path}: {key} must be a positive finite number (m or rad); got "
                                        f"{json.dumps(value)[:40]}")
        values.append(float(value))
    try:
        _check_sigmas(*values)
    except IncompatibleMapsError as e:
        raise IncompatibleMapsError(f"{path}: sigma_xy, sigma_yaw: {e}") from None
    return values[0], values[1]
