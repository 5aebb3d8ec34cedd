"""Per-robot noise models as configuration: a TOML file with odometry and sensor noise (and calibration).

File format (``tomllib``; written atomically by :meth:`NoiseModel.save`)::

    format = "p3at-noise-model"
    version = 1
    robot = "MRCLAM_Dataset2/Robot1"
    platform = "iRobot Create (MRCLAM)"
    source = "where the numbers come from"

    [odometry]                 # random walk (FastSLAMConfig's motion model): variances grow with the motion
    xy_var_per_m = 0.0025      # m² of along/across-track error per metre driven
    theta_var_per_rad = 0.01   # rad² of heading error per radian turned
    theta_var_per_m = 0.01     # rad² of heading error per metre driven
    translation_scale = 1.0    # calibration: true distance / odometry distance
    rotation_scale = 1.0       # calibration: true turn / odometry turn
    heading_bias_per_m = 0.0   # calibration: rad of heading the robot turns per metre of odometry driven (a curve
                               #   on a straight run: UMBmark's type-A error, unequal wheels); optional, 0 if absent
    lag_s = 0.0                # calibration: s by which the odometry leads the motion (commanded velocities: the
                               #   pose at t is the odometry's at t − lag_s); optional, 0 if absent
    forward_deficit_per_rad = 0.0  # calibration: m of travel the robot does not make per radian of odometry turn
                               #   (MRCLAM's Creates make 0.65 of the commanded distance in arcs); optional, 0 if absent
    turn_xy_inflation = 1.0    # × the x/y variance of the increments of a turn (≥ 2 rad/m): a turn's forward error
                               #   persists through it, so its increments are not independent; optional, 1 if absent
    heading_drift_sigma_per_m = 0.0  # a drifting heading bias per metre (rad/m): a first-order Gauss–Markov process
    heading_drift_tau_s = 0.0  #   with this stationary σ and correlation time τ (s) that the filter carries per
                               #   particle (FastSLAMConfig.odom_heading_drift_*); optional, 0 (off) if absent
    theta_var_per_s = 0.0      # rad² of heading error per second, moving or not (bumps, pushes, slip: a stopped
                               #   robot's heading wanders too); optional, 0 if absent
    stall_sigma_s = 0.0        # σ (s) of the random stall after a one-sample dip of the commanded velocity: the
                               #   increment holding a dip gets (ω σ)² on θ, (v σ)² on x, y (estimation.odometry_stall;
                               #   needs the log's velocity samples); optional, 0 (none) if absent

    [range_bearing]            # optional: a planar range-bearing sensor
    range_sigma_m = 0.02       # σ_r(r) = range_sigma_m + range_sigma_per_m · r
    range_sigma_per_m = 0.04
    bearing_sigma_rad = 0.01
    bearing_offset_rad = 0.0   # calibration: subtracted from every bearing (the sensor's yaw on the robot)
    fov_rad = 6.283185307179586   # footprint: horizontal field of view, and the ranges at which it reports
    min_range_m = 0.0
    max_range_m = 30.0
    range_correlation = 0.0    # lag-1 correlation of consecutive sightings' residuals (see variance_inflation)
    bearing_correlation = 0.0
    range_offset_m = 0.0       # calibration (optional, identity if absent): r ← a + r·(b₀ + b₁φ + b₂φ²), the
    range_scale = 1.0          #   measured φ; a camera that reports depth along its axis, not range, has b₂ ≈ ½
    range_scale_per_rad = 0.0  #   (1/cos φ to second order; see RangeBearingNoise.corrected)
    range_scale_per_rad2 = 0.0

    [stereo]                   # optional: a stereo head (the front end's TriangulationNoise)
    sigma_u_px = 0.5
    sigma_v_px = 0.5
    sigma_d_px = 0.3

    [fit]                      # optional, informational: figures of the estimation that wrote the file

:func:`estimate_noise` fits a model from logs with ground truth (``p3at slam noise``). Defaults for a P3-AT on
its wheels with the Videre head: :data:`P3AT_VIDERE_DEFAULT`, with its provenance in ``source``.
"""
from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar, nnls

from .datasets import RangeBearingLog
from .errors import EstimationError
from .fastslam.config import FastSLAMConfig
from .fastslam.motion import increment_variance, turn_spans, turning
from .fileio import InputTooLargeError, atomic_write_bytes, read_bounded, special_file_kind
from .geometry import between, wrap_angle
from .odometry_consistency import fit_heading_drift
from .odometry_stall import MAX_STALL_SIGMA_S, command_stall_variance, fit_stall

FORMAT_NAME = "p3at-noise-model"
FORMAT_VERSION = 1
MAX_FILE_BYTES = 1 << 20     # a noise model is a few hundred bytes; refuse anything absurd before parsing
SIGNED_FIELDS = ("bearing_offset_rad", "heading_bias_per_m", "range_offset_m", "range_scale_per_rad",
                 "range_scale_per_rad2")
MAX_HEADING_BIAS_PER_M = 0.5   # rad/m: a 2 m circle when commanded straight is a broken robot, not a calibration
MAX_ODOMETRY_LAG_S = 1.0       # s: a drive that answers its commands a second late is not a calibration
MAX_FORWARD_DEFICIT_PER_RAD = 0.5  # m/rad: a robot that loses half a metre per radian turned is not calibrated
MAX_TURN_XY_INFLATION = 100.0      # beyond, a turn's odometry says nothing of its travel: not a calibration
MAX_HEADING_DRIFT_PER_M = 1.0      # rad/m: σ of the drifting heading bias; beyond, the heading says nothing
# magnitudes beyond which a value describes no robot or sensor (and its square overflows the filter's arithmetic:
# a σ of 1e308 m was an OverflowError, a variance of 1e308 dozens of RuntimeWarnings); the others have checks below
MAGNITUDE_BOUNDS = {"xy_var_per_m": 100.0, "theta_var_per_rad": 100.0, "theta_var_per_m": 100.0,   # m²/m, rad²/…
                    "theta_var_per_s": 100.0,                                                      # rad²/s
                    "heading_drift_tau_s": 1e6,                                                    # s (11 days)
                    "range_sigma_m": 1e3, "range_sigma_per_m": 1e3, "bearing_sigma_rad": 2 * math.pi,  # m, m/m, rad
                    "bearing_offset_rad": math.pi, "max_range_m": 1e4,   # rad, m (min_range_m < max_range_m)
                    "range_offset_m": 1e3, "range_scale_per_rad": 10.0, "range_scale_per_rad2": 10.0,
                    "sigma_u_px": 1e4, "sigma_v_px": 1e4, "sigma_d_px": 1e4}                      # px
TURN_STEP_S = 0.25                 # the increments on which a turn's overdispersion is measured (a frame interval)
TURN_MIN_INCREMENTS = 4            # a turn shorter than this says nothing of the errors' persistence
# range bands (label, upper edge m) of the fitted detection probabilities ([fit] detection_probability_<label>)
DETECTION_BANDS = (("below_3m", 3.0), ("3_to_5m", 5.0), ("beyond_5m", math.inf))


class NoiseModelError(EstimationError, ValueError):
    """A noise-model file is missing, malformed or holds an impossible value (the message names file and key)."""


@dataclass(frozen=True)
class OdometryNoise:
    xy_var_per_m: float
    theta_var_per_rad: float
    theta_var_per_m: float
    translation_scale: float = 1.0
    rotation_scale: float = 1.0
    heading_bias_per_m: float = 0.0      # rad per metre of odometry distance (signed; see calibrate_increments)
    lag_s: float = 0.0                   # the odometry leads the motion by this (see NoiseModel.odometry_times)
    forward_deficit_per_rad: float = 0.0  # m of travel lost per radian of odometry turn (see calibrate_increments)
    turn_xy_inflation: float = 1.0        # × the x/y variance in turns (FastSLAMConfig.odom_turn_xy_inflation)
    heading_drift_sigma_per_m: float = 0.0  # σ_b rad/m of a Gauss–Markov heading bias per metre; 0: none
    heading_drift_tau_s: float = 0.0        # its correlation time τ s (> 0 when σ_b > 0)
    theta_var_per_s: float = 0.0            # rad² of heading error per second (FastSLAMConfig.odom_theta_var_per_s)
    stall_sigma_s: float = 0.0              # σ s of the stall after a command dip (command_stall_variance); 0: none

    @property
    def heading_drift(self) -> tuple[float, float] | None:
        """(σ_b rad/m, τ s) of the drifting heading bias, or None when there is none (σ_b = 0)."""
        if self.heading_drift_sigma_per_m == 0.0:
            return None
        return (self.heading_drift_sigma_per_m, self.heading_drift_tau_s)


@dataclass(frozen=True)
class RangeBearingNoise:
    range_sigma_m: float
    range_sigma_per_m: float
    bearing_sigma_rad: float
    bearing_offset_rad: float = 0.0
    fov_rad: float = 2.0 * math.pi       # the sensor's footprint (FastSLAM: candidates and negative evidence)
    min_range_m: float = 0.0
    max_range_m: float = 30.0
    range_correlation: float = 0.0       # lag-1 correlation of consecutive sightings' residuals of one landmark
    bearing_correlation: float = 0.0
    range_offset_m: float = 0.0          # calibration of the range (see corrected); identity by default
    range_scale: float = 1.0
    range_scale_per_rad: float = 0.0
    range_scale_per_rad2: float = 0.0

    def corrected(self, ranges, bearings) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated (ranges, bearings) (N,) from measured ones (N,): φ − ``bearing_offset_rad``, and
        r' = a + r·(b₀ + b₁φ + b₂φ²) with the measured φ (a = ``range_offset_m``, b₀ = ``range_scale``,
        b₁ = ``range_scale_per_rad``, b₂ = ``range_scale_per_rad2``).

        Why this form: a camera that measures a landmark's distance from its apparent size measures the depth
        along its optical axis, d = r·cos(φ − ψ) (ψ: the axis's yaw), not the range; r = d / cos(φ − ψ) =
        d·(1 + ψ² / 2 − ψφ + φ² / 2 + O(φ⁴)) is, within the field of view (|φ| ≲ 0.6 rad: the next term is
        under 0.5 %), this polynomial with b₂ ≈ ½ b₀, b₁ ≈ −ψ b₀; a and b₀ − 1 absorb the size's offset and
        scale. MRCLAM's five cameras all show it (docs/fastslam-history.md, "Session 8")."""
        r = np.asarray(ranges, float)
        phi = np.asarray(bearings, float)
        scale = self.range_scale + self.range_scale_per_rad * phi + self.range_scale_per_rad2 * phi ** 2
        return self.range_offset_m + r * scale, phi - self.bearing_offset_rad

    def variance_inflation(self) -> tuple[float, float]:
        """(range, bearing) factors (1 + ρ)/(1 − ρ) on the variances: an AR(1) series of N sightings with lag-1
        correlation ρ carries the information of N (1 − ρ)/(1 + ρ) independent ones, so a filter that takes them
        as independent must see each one's variance multiplied by this to stay consistent."""
        return tuple((1.0 + max(rho, 0.0)) / (1.0 - max(rho, 0.0)) for rho in (self.range_correlation,
                                                                               self.bearing_correlation))

    def fastslam_overrides(self) -> dict:
        """The FastSLAMConfig fields of the sensor's footprint."""
        return {"fov_horizontal": float(self.fov_rad), "min_range": float(self.min_range_m),
                "max_range": float(self.max_range_m)}

    def range_sigma(self, ranges) -> np.ndarray:
        """σ_r (N,) m at ranges (N,) m."""
        return self.range_sigma_m + self.range_sigma_per_m * np.asarray(ranges, float)


@dataclass(frozen=True)
class StereoNoise:
    sigma_u_px: float
    sigma_v_px: float
    sigma_d_px: float


@dataclass(frozen=True)
class NoiseModel:
    """One robot's noise: odometry always; a range-bearing sensor, a stereo head or both."""

    odometry: OdometryNoise
    range_bearing: RangeBearingNoise | None = None
    stereo: StereoNoise | None = None
    robot: str = "robot"
    platform: str = ""
    source: str = ""
    fit: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for section in (self.odometry, self.range_bearing, self.stereo):
            if section is None:
                continue
            for f in fields(section):
                value = getattr(section, f.name)
                signed = f.name in SIGNED_FIELDS
                if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value) \
                        or (not signed and value < 0):
                    raise NoiseModelError(f"{f.name} must be a finite number{'' if signed else ' >= 0'}, "
                                          f"not {value!r}")
                bound = MAGNITUDE_BOUNDS.get(f.name)
                if bound is not None and abs(value) > bound:
                    raise NoiseModelError(f"{f.name} must lie within {'±' if signed else '[0, '}{bound:g}"
                                          f"{'' if signed else ']'}, not {value!r}")
        scales = (self.odometry.translation_scale, self.odometry.rotation_scale)
        if not all(0.5 <= s <= 2.0 for s in scales):
            raise NoiseModelError(f"odometry scales must lie in [0.5, 2] (a calibration, not a new robot), "
                                  f"not {scales}")
        if not abs(self.odometry.heading_bias_per_m) <= MAX_HEADING_BIAS_PER_M:
            raise NoiseModelError(f"heading_bias_per_m must lie in [-{MAX_HEADING_BIAS_PER_M}, "
                                  f"{MAX_HEADING_BIAS_PER_M}] rad/m (a calibration, not a turn), not "
                                  f"{self.odometry.heading_bias_per_m}")
        if not self.odometry.forward_deficit_per_rad <= MAX_FORWARD_DEFICIT_PER_RAD:
            raise NoiseModelError(f"forward_deficit_per_rad must lie in [0, "
                                  f"{MAX_FORWARD_DEFICIT_PER_RAD}] m/rad (a calibration), not "
                                  f"{self.odometry.forward_deficit_per_rad}")
        if not 1.0 <= self.odometry.turn_xy_inflation <= MAX_TURN_XY_INFLATION:
            raise NoiseModelError(f"turn_xy_inflation must lie in [1, {MAX_TURN_XY_INFLATION}] (a variance "
                                  f"inflation), not {self.odometry.turn_xy_inflation}")
        drift_sigma, drift_tau = self.odometry.heading_drift_sigma_per_m, self.odometry.heading_drift_tau_s
        if not drift_sigma <= MAX_HEADING_DRIFT_PER_M:
            raise NoiseModelError(f"heading_drift_sigma_per_m must lie in [0, {MAX_HEADING_DRIFT_PER_M}] rad/m, not "
                                  f"{drift_sigma}")
        if drift_sigma > 0 and not drift_tau > 0:
            raise NoiseModelError(f"heading_drift_tau_s must be > 0 when heading_drift_sigma_per_m is > 0, not "
                                  f"{drift_tau}")
        if not self.odometry.stall_sigma_s <= MAX_STALL_SIGMA_S:
            raise NoiseModelError(f"stall_sigma_s must lie in [0, {MAX_STALL_SIGMA_S}] s (a drive's hiccup, not a "
                                  f"stop), not {self.odometry.stall_sigma_s}")
        if not self.odometry.lag_s <= MAX_ODOMETRY_LAG_S:
            raise NoiseModelError(f"lag_s must lie in [0, {MAX_ODOMETRY_LAG_S}] s (a calibration), not "
                                  f"{self.odometry.lag_s}")
        rb = self.range_bearing
        if rb is not None and not (rb.range_sigma_m > 0 and rb.bearing_sigma_rad > 0):
            raise NoiseModelError("range_sigma_m and bearing_sigma_rad must be > 0")
        if rb is not None and not (0 < rb.fov_rad <= 2 * math.pi and rb.min_range_m < rb.max_range_m):
            raise NoiseModelError("the footprint needs 0 < fov_rad <= 2π and min_range_m < max_range_m")
        if rb is not None and not 0.5 <= rb.range_scale <= 2.0:
            raise NoiseModelError(f"range_scale must lie in [0.5, 2] (a calibration, not a new sensor), not "
                                  f"{rb.range_scale}")
        if rb is not None and not (0 <= rb.range_correlation < 0.99 and 0 <= rb.bearing_correlation < 0.99):
            raise NoiseModelError("range_correlation and bearing_correlation must lie in [0, 0.99)")

    def fastslam_overrides(self) -> dict:
        """The FastSLAMConfig fields this model sets (its motion model; a range-bearing sensor's footprint)."""
        o = self.odometry
        values = {"odom_xy_var_per_m": float(o.xy_var_per_m), "odom_theta_var_per_rad": float(o.theta_var_per_rad),
                  "odom_theta_var_per_m": float(o.theta_var_per_m),
                  "odom_turn_xy_inflation": float(o.turn_xy_inflation),
                  "odom_heading_drift_sigma_per_m": float(o.heading_drift_sigma_per_m),
                  "odom_heading_drift_tau_s": float(o.heading_drift_tau_s),
                  "odom_theta_var_per_s": float(o.theta_var_per_s)}
        if self.range_bearing is not None:
            values.update(self.range_bearing.fastslam_overrides())
        return values

    def existence_overrides(self) -> dict:
        """The FastSLAMConfig fields of the sensor's detection rates (``estimation/fastslam/existence.py``), from
        the fit's P(detect) per range band and its outlier share as the false-alarm probability; empty if the
        model does not carry them (then the filter keeps its constant hit/miss log-odds)."""
        p_d = [self.fit.get(f"detection_probability_{band}") for band, _ in DETECTION_BANDS]
        p_fa = self.fit.get("sensor_outlier_fraction")
        if any(not isinstance(p, int | float) or not math.isfinite(p) for p in [*p_d, p_fa]):
            return {}
        rho = self.fit.get("detection_correlation", 0.0)
        rho = float(np.clip(rho, 0.0, 0.95)) if isinstance(rho, int | float) and math.isfinite(rho) else 0.0
        return {"detection_probabilities": tuple(float(np.clip(p, 0.01, 0.99)) for p in p_d),
                "detection_range_edges": tuple(edge for _, edge in DETECTION_BANDS[:-1]),
                "false_alarm_probability": float(np.clip(p_fa, 1e-3, 0.5)), "detection_correlation": rho}

    def calibrate_increments(self, increments: np.ndarray) -> np.ndarray:
        """Odometry increments (T, 3) with the model's calibration applied: the scales, the heading bias per
        metre of the increment's odometry distance (its chord: increments between frames are short), and the
        forward deficit per radian of its odometry turn (the chord shortened by ``forward_deficit_per_rad``·|Δθ|,
        never below zero; see _calibrated)."""
        o = self.odometry
        return _calibrated(increments, (o.translation_scale, o.translation_scale, o.rotation_scale),
                           o.heading_bias_per_m, o.forward_deficit_per_rad)

    def odometry_times(self, times) -> np.ndarray:
        """The odometry's times (T,) for poses at ``times`` (T,): t − lag_s. Why: MRCLAM's odometry is the commanded
        velocity, which the robot follows ~0.17 s late (docs/fastslam-history.md "Session 9"): at the end of a turn on
        the spot the odometry has stopped while the robot still turns, and landmarks sighted then are placed with that
        heading error."""
        return np.asarray(times, float) - self.odometry.lag_s

    # -- files -------------------------------------------------------------------------------------------------
    def to_toml(self) -> str:
        lines = ["# p3at-fusion noise model: read by `p3at slam dataset --noise`, written by `p3at slam noise`",
                 f"format = {_toml_value(FORMAT_NAME)}", f"version = {FORMAT_VERSION}",
                 f"robot = {_toml_value(self.robot)}", f"platform = {_toml_value(self.platform)}",
                 f"source = {_toml_value(self.source)}"]
        for name in ("odometry", "range_bearing", "stereo"):
            section = getattr(self, name)
            if section is not None:
                lines += ["", f"[{name}]"] + [f"{k} = {_toml_value(v)}" for k, v in asdict(section).items()]
        if self.fit:
            lines += ["", "[fit]"] + [f"{k} = {_toml_value(v)}" for k, v in self.fit.items()]
        return "\n".join(lines) + "\n"

    def save(self, path) -> None:
        """Write the model as TOML, atomically."""
        atomic_write_bytes(path, self.to_toml().encode())

    @classmethod
    def load(cls, path) -> NoiseModel:
        """Read a file written by :meth:`save` (or by hand); any defect is a NoiseModelError naming file and key."""
        path = Path(path)
        try:
            text = read_bounded(path, MAX_FILE_BYTES).decode("utf-8")   # never waits on a FIFO
            if not text.strip():   # said "key 'format' is None" (a FIFO nothing writes to reads as empty)
                what = special_file_kind(path)
                raise NoiseModelError(f"{path}: {'an empty file' if what is None else what + ' that gave nothing'}, "
                                      "not a noise model (TOML, see `p3at slam noise`)")
            data = tomllib.loads(text)
        except InputTooLargeError as e:
            raise NoiseModelError(f"{path}: {e}; a noise model has at most {MAX_FILE_BYTES}") from None
        except FileNotFoundError:
            raise NoiseModelError(f"{path}: no such noise-model file") from None
        except OSError as e:
            raise NoiseModelError(f"{path}: cannot read the noise model ({e.strerror or e})") from None
        except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            raise NoiseModelError(f"{path}: not a readable TOML noise model ({e})") from None
        except RecursionError:  # tomllib nests arrays and inline tables by recursion
            raise NoiseModelError(f"{path}: not a readable TOML noise model (nested too deeply)") from None
        return cls.from_dict(data, str(path))

    @classmethod
    def from_dict(cls, data: dict, where: str = "<noise model>") -> NoiseModel:
        if "format" not in data:   # said "key 'format' is None"
            raise NoiseModelError(f"{where}: no key 'format' (a noise model says format = {FORMAT_NAME!r})")
        if data.get("format") != FORMAT_NAME:
            raise NoiseModelError(f"{where}: key 'format' is {data.get('format')!r}, not {FORMAT_NAME!r}")
        if data.get("version") != FORMAT_VERSION:
            raise NoiseModelError(f"{where}: version {data.get('version')!r} is not supported (this reader knows "
                                  f"{FORMAT_VERSION})")
        known = {"format", "version", "robot", "platform", "source", "odometry", "range_bearing", "stereo", "fit"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise NoiseModelError(f"{where}: unknown key(s) {', '.join(unknown)}")
        if "odometry" not in data:
            raise NoiseModelError(f"{where}: section [odometry] is missing")
        sections = {}
        for name, kind in (("odometry", OdometryNoise), ("range_bearing", RangeBearingNoise), ("stereo", StereoNoise)):
            if name not in data:
                continue
            values = data[name]
            if not isinstance(values, dict):
                raise NoiseModelError(f"{where}: {name} must be a [section]")
            names = {f.name for f in fields(kind)}
            extra = sorted(set(values) - names)
            required = {f.name for f in fields(kind) if f.default is f.default_factory}  # no default: required
            missing = sorted(required - set(values))
            if extra or missing:
                raise NoiseModelError(f"{where}: [{name}] " + (f"unknown key(s) {', '.join(extra)}" if extra else
                                                               f"lacks {', '.join(missing)}"))
            for key, value in values.items():
                if not isinstance(value, int | float) or isinstance(value, bool):
                    raise NoiseModelError(f"{where}: [{name}] {key} must be a number, not {repr(value)[:60]}")
                if isinstance(value, int) and not abs(value) <= 2**63:  # float() of a 400-digit int overflows
                    raise NoiseModelError(f"{where}: [{name}] {key} is out of range ({len(str(value))} digits)")
            sections[name] = kind(**{k: float(v) for k, v in values.items()})
        for key in ("robot", "platform", "source"):
            if not isinstance(data.get(key, ""), str):
                raise NoiseModelError(f"{where}: key '{key}' must be a string")
        fit = data.get("fit", {})
        if not isinstance(fit, dict):
            raise NoiseModelError(f"{where}: fit must be a [section]")
        for key, value in fit.items():  # figures read back as floats (existence_overrides)
            if isinstance(value, int) and not abs(value) <= 2**63:
                raise NoiseModelError(f"{where}: [fit] {key} is out of range ({len(str(value))} digits)")
            # what save() cannot write back (a model given to --self-calibrate is written out with its [fit] after
            # the work: a datetime, a table, NaN or a key needing quotes failed there, naming no file)
            if not _BARE_KEY.fullmatch(key):
                raise NoiseModelError(f"{where}: [fit] key {key[:40]!r} is not a bare key (letters, digits, _ and -)")
            try:
                _toml_value(value)
            except NoiseModelError as e:
                raise NoiseModelError(f"{where}: [fit] {key}: {e} (a noise model's figures are numbers, text, "
                                      "true/false or lists of them)") from None
        try:
            return cls(sections["odometry"], sections.get("range_bearing"), sections.get("stereo"),
                       data.get("robot", "robot"), data.get("platform", ""), data.get("source", ""), dict(fit))
        except NoiseModelError as e:
            raise NoiseModelError(f"{where}: {e}") from None


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")   # a TOML key written without quotes


def _toml_value(value) -> str:
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        if not math.isfinite(value):
            raise NoiseModelError(f"cannot write the non-finite value {value}")
        return repr(float(value))      # numpy's repr is "np.float64(1.0)", which no TOML reader takes
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t")
        # any other control character as \uXXXX: TOML's basic strings may not hold one (the file would not read)
        escaped = re.sub(r"[\x00-\x1f\x7f]", lambda m: f"\\u{ord(m.group()):04x}", escaped)
        return f'"{escaped}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise NoiseModelError(f"cannot write {type(value).__name__} values to TOML")


# -- defaults ------------------------------------------------------------------------------------------------
P3AT_VIDERE_DEFAULT = NoiseModel(
    odometry=OdometryNoise(xy_var_per_m=0.03 ** 2, theta_var_per_rad=0.05 ** 2, theta_var_per_m=0.02 ** 2),
    stereo=StereoNoise(sigma_u_px=0.5, sigma_v_px=0.5, sigma_d_px=0.3),
    robot="p3at", platform="Pioneer P3-AT (skid steer, wheel encoders) with a Videre STH-MDCS2 head",
    source="NOT measured: no P3-AT log with ground truth is available to this project. Odometry: the values "
           "FastSLAMConfig has always used (shared/reference gives encoder and geometry facts, no error figures); "
           "stereo: the front end's TriangulationNoise. Replace them with `p3at slam noise` on a log of your robot.",
)


# -- estimation from logs with ground truth ----------------------------------------------------------------------
ODOMETRY_WINDOW_S = 5.0       # see estimate_noise: the errors are time-correlated, so the window matters
MAX_VARIANCE_INFLATION = 100.0  # turn and distance more collinear than this: no heading bias is fitted
OUTLIER_MADS = 4.0            # sensor residuals beyond this many robust σ are outliers (misreads, glitches)
# The calibrations that together make MRCLAM's smoothed known-ID maps honest in their start frame
# (docs/fastslam-history.md, "Session 16: the odometry's variance in turns" and "Session 17: the data set's default"):
# what `p3at slam dataset` fits from the log's own ground truth when no noise model is given. Each is per robot (the
# cameras' range and bearing offsets differ by up to 10 cm and 0.012 rad), so a model fitted on other robots does not
# serve. The stall after the command's dips (session 41 (A)) is one since session 42: on MRCLAM (seed 0) it takes
# robot 1's known-ID map from 93 to 100 % within and leaves the other four's within as they were; the chain in sample
# keeps 15 names on all five robots with it (docs/fastslam-history.md, "Session 42: the stall after the command's
# dips made a default (lead)"). On a log without dips it fits 0: no term.
DATASET_CALIBRATIONS = {"range_calibration": True, "heading_bias": True, "odometry_lag": True, "turn_variance": True,
                        "command_stall": True}


@dataclass(frozen=True)
class NoiseEstimate:
    """A fitted model, and the odometry fit at other windows (rows: window_s, σ_xy/√m, σ_θ/√rad, σ_θ/√m)."""

    model: NoiseModel
    odometry_by_window: np.ndarray


def estimate_noise(logs: Sequence[RangeBearingLog], *, window_s: float = ODOMETRY_WINDOW_S,
                   robot: str | None = None, platform: str = "", heading_bias: bool = False,
                   sensor_correlation: str = "lag1", range_calibration: bool = False,
                   odometry_lag: bool = False, turn_translation: bool = False,
                   turn_variance: bool = False, heading_drift: bool = False,
                   time_variance: bool = False, calibration_per_log: bool = False,
                   command_stall: bool = False) -> NoiseEstimate:
    """Fit a noise model from logs with ground truth (one robot's, or several pooled).

    ``heading_drift=True``: also a drifting heading bias per metre (σ_b, τ; see :func:`_with_heading_drift`).

    Odometry. The log's span is cut into windows of ``window_s``; in each, the odometry increment u and the
    true increment g (from the ground truth) give the error e = g − u in the robot frame at the window's start.
    First the calibration: the rotation scale and the heading bias per metre by least squares
    (g_θ ≈ k_r u_θ + c·d, d the window's odometry distance) with ``heading_bias=True``; by default, or for a log
    whose turns and distances are proportional so that the two cannot be told apart, c = 0 (see
    _heading_calibration; off by default because on MRCLAM it did not improve the maps, docs/fastslam-history.md); then,
    the turns calibrated, the translation scale by least squares on the window's displacement vectors (which
    scale linearly with it). Then
    the random-walk variances q = (q_xy, q_θ/rad, q_θ/m) of the calibrated steps:
    the model's covariance of a window's error is linear in q (each step's noise, propagated to the window's end
    through the composition: a heading error also moves the end sideways), so q is the non-negative least
    squares fit of every window's e eᵀ to it (:func:`_random_walk_fit`). On MRCLAM the variance per metre still
    grows with the window (the odometry is commanded velocity, so its errors are correlated over seconds);
    the model is a random walk, so the window chosen is the time scale on which the filter must trust the
    odometry alone: the default 5 s is longer than the gaps between sightings, and the fits at other windows
    are returned beside it (``odometry_by_window``) so that the choice can be judged.

    Sensor. Each sighting is predicted from the true pose and the landmark's true position: residuals
    Δr = r − r̂, Δφ = φ − φ̂. The bearing offset is the residuals' median (the sensor's yaw on the robot);
    outliers (beyond OUTLIER_MADS robust σ: misread barcodes, sightings during Vicon glitches) are counted and
    set aside; σ_r(r) = a + b·r is fitted (non-negative least squares) to |Δr|·√(π/2) of the inliers — the
    mean absolute value of a zero-mean Gaussian is σ·√(2/π) — so the range's bias (the short-range bias the
    data set's authors report) counts as noise, not as a correction; σ_φ is the inliers' RMS about the offset.
    ``sensor_correlation``: how ``range_correlation`` / ``bearing_correlation`` are measured: ``"lag1"``
    (default) the lag-1 correlation of consecutive sightings of a landmark (an AR(1) assumed beyond it: on MRCLAM
    it understates the bearing's inflation 1.5-2x and overstates the range's 2-4x); ``"passes"`` the ρ whose
    AR(1) inflation (1 + ρ)/(1 − ρ) equals the measured one of whole passes (:func:`_pass_inflation`): what a
    filter taking a pass's sightings as independent needs over a pass. Not the default: on MRCLAM it improved
    known-ID maps on three seeds but made the leave-one-out and unknown-association runs worse
    (docs/fastslam-history.md). ``range_calibration``: first fit the range's calibration r_true ≈ a + r·(b₀ + b₁φ +
    b₂φ²) (measured r, φ; see :meth:`RangeBearingNoise.corrected`) by least squares, refitted three times on the
    sightings within OUTLIER_MADS robust σ, and take every range residual, σ_r and correlation after it; off: the
    identity. ``calibration_per_log`` (several logs pooled): the range calibration (with ``range_calibration``)
    and the bearing offset are fitted to each log on its own, and the σ's and correlations are measured on each
    log's residuals about its own calibration; the model carries the logs' mean calibration (the typical camera;
    its b₂ is what a self-calibration holds fixed), and [fit] each log's (``per_log_*``, in the logs' order). Why:
    cameras differ (MRCLAM's range offsets −0.011 to −0.110 m, scales 0.950-1.005); pooled residuals about one
    calibration hold each camera's bias, which reads as noise 4-9x too large and as a lag-1 correlation of 0.8-0.9
    (docs/fastslam-history.md, "Session 36 ... (B)"). The σ's of this fit are the ones to give a robot whose own
    calibration is estimated apart (:mod:`estimation.camera_calibration`). ``odometry_lag``: first fit the time by
    which the odometry leads the motion (:func:`_odometry_lag`: the
    lag that minimises the heading increments' error at the filter's frame interval) and fit everything else on the
    odometry read that much earlier; off: 0.
    ``turn_translation``: fit the translation scale k jointly with a forward deficit per radian turned c (each
    50 Hz step's distance d → max(d − c·|Δθ|, 0), then scaled by k; :func:`_calibrated`) on the same windows,
    c by a bounded search on [0, MAX_FORWARD_DEFICIT_PER_RAD] with k in closed form for each c, and c's standard
    error from the profile's curvature; off: c = 0 (one translation scale for all motion). Why: MRCLAM's robots
    cover 0.65 of the commanded distance in arcs and all of it straight (docs/fastslam-history.md "Session 16 (Q)").
    ``turn_variance``: fit ``turn_xy_inflation``, the turns' overdispersion (:func:`_turn_inflation`): on
    increments of TURN_STEP_S with everything above calibrated, z = (true − odometry forward travel) / σ_xy of the
    fitted random walk; over each turn (≥ TURN_MIN_INCREMENTS consecutive increments of
    ``estimation.fastslam.motion.turning``) Σz/√n is a unit normal if the increments' errors are independent; the
    inflation is its mean square over the turns (≥ 1; a mean error counts: a bias the calibration left is a
    persistent error too); off: 1. Why: the smoothed MRCLAM maps' start frames fail on the forward travel of the
    first turns, correlated through each turn (docs/fastslam-history.md "Session 16 (P)").
    ``time_variance``: fit a fourth random-walk variance, ``theta_var_per_s`` (rad² of heading per second, moving or
    not), in the same non-negative least squares (each step's heading noise q_θ/s × its duration, propagated like the
    others; :func:`_odometry_windows`' time column), and write the three-term fit's q_θ/rad and q_θ/m beside it in
    [fit]; off: 0. Why and what it does and does not explain: docs/fastslam-history.md "Session 35: a heading
    variance per second (A)".
    ``command_stall``: fit ``stall_sigma_s``, the σ of the random stall after a one-sample dip of the commanded
    velocity (:func:`estimation.odometry_stall.fit_stall`, on the odometry calibrated as above; needs the logs'
    velocity samples), its figures in [fit]; off: 0. Why: MRCLAM's robots stop for a random while after each such dip
    while their odometry goes on (docs/fastslam-history.md "Session 41 (A)").
    """
    if sensor_correlation not in ("lag1", "passes"):
        raise ValueError(f"sensor_correlation must be 'lag1' or 'passes', not {sensor_correlation!r}")
    logs = list(logs)
    if not logs:
        raise ValueError("estimate_noise needs at least one log")
    if not window_s > 0:
        raise ValueError(f"window_s must be > 0, not {window_s}")
    for log in logs:
        if not log.has_ground_truth:
            raise ValueError(f"{log.name}: noise estimation needs ground truth, and the log has none")

    lag, lag_fit = _odometry_lag(logs) if odometry_lag else (0.0, {})
    windows = [_odometry_windows(log, window_s, lag_s=lag) for log in logs]
    u = np.concatenate([w[0] for w in windows])
    g = np.concatenate([w[1] for w in windows])
    if len(u) < 10:
        raise ValueError(f"only {len(u)} odometry windows of {window_s} s: too short a log for a fit")
    distance = np.concatenate([w[2][:, 0, 0, 0] for w in windows])    # odometry metres per window
    rotation_scale, bias, bias_se = _heading_calibration(u[:, 2], distance if heading_bias else None, g[:, 2])
    bias_fit = {} if not heading_bias else {"heading_bias_per_m_standard_error": bias_se} if math.isfinite(bias_se) \
        else {"heading_bias_note": "not fitted: the windows' turns and distances are proportional (a bias per "
                                   "metre cannot be told from a rotation scale)"}
    # with the turns calibrated, the chain's positions scale linearly with the translation scale: regress on them
    translation_scale, deficit, deficit_fit = _translation_calibration(logs, window_s, rotation_scale, bias, lag,
                                                                       g, turn_translation)
    scales = np.array([translation_scale, translation_scale, rotation_scale])
    q_xy, q_theta_rad, q_theta_m, *q_theta_s = _random_walk_fit(
        [_odometry_windows(log, window_s, scales, bias, lag, deficit, time_variance) for log in logs])
    q_theta_s = q_theta_s[0] if q_theta_s else 0.0
    time_fit = {}
    if time_variance:   # the three-term fit beside it: what the time term took from the others
        without = _random_walk_fit([_odometry_windows(log, window_s, scales, bias, lag, deficit) for log in logs])
        time_fit = {"theta_var_per_rad_without_time": without[1], "theta_var_per_m_without_time": without[2]}
    inflation, turn_fit = (_turn_inflation(logs, scales, bias, lag, deficit, q_xy) if turn_variance
                           else (1.0, {}))
    stall, stall_fit = (fit_stall(logs, lag, lambda inc: _calibrated(inc, scales, bias, deficit)) if command_stall
                        else (0.0, {}))
    by_window = []
    for w in sorted({0.5, 1.0, 2.0, 5.0, 10.0, 20.0, float(window_s)}):
        other = [_odometry_windows(log, w, scales, bias, lag, deficit) for log in logs]
        if sum(len(o[0]) for o in other) >= 10:
            by_window.append((w, *np.sqrt(_random_walk_fit(other))))

    residual_r, residual_b, ranges, bearings, follows, true_ranges = [], [], [], [], [], []
    for log in logs:
        if len(log) == 0:
            continue
        pose = log.true_pose(log.sighting_times)
        known = np.isin(log.landmark_ids, log.truth_ids)
        target = log.truth_positions[np.searchsorted(log.truth_ids, log.landmark_ids[known])]
        d = target - pose[known, :2]
        true_ranges.append(np.hypot(d[:, 0], d[:, 1]))
        residual_r.append(log.ranges[known] - true_ranges[-1])
        residual_b.append(wrap_angle(log.bearings[known] - (np.arctan2(d[:, 1], d[:, 0]) - pose[known, 2])))
        ranges.append(log.ranges[known])
        bearings.append(log.bearings[known])
        follows.append(_consecutive(log.sighting_times[known], log.landmark_ids[known]))
    range_bearing = None
    range_fit = _NO_RANGE_CALIBRATION
    per_log_fit: dict = {}
    if range_calibration and residual_r and sum(len(r) for r in residual_r) >= 20:
        range_fit = _range_calibration(np.concatenate(ranges), np.concatenate(bearings), np.concatenate(true_ranges))
        own = [_range_calibration(r, b, t) if calibration_per_log else range_fit
               for r, b, t in zip(ranges, bearings, true_ranges, strict=True)]
        residual_r = [RangeBearingNoise(1.0, 0.0, 1.0, **dict(zip(_RANGE_CALIBRATION, f, strict=True)))
                      .corrected(r, b)[0] - t for f, r, b, t in zip(own, ranges, bearings, true_ranges, strict=True)]
        if calibration_per_log:   # the model's: the logs' mean (the typical camera)
            range_fit = tuple(float(v) for v in np.mean(own, axis=0))
            per_log_fit.update({f"per_log_{name}": [float(f[i]) for f in own]
                                for i, name in enumerate(_RANGE_CALIBRATION)})
    if calibration_per_log and residual_b:   # each log's bearing residuals about its own offset, moved to the
        own_offsets = [float(np.median(b)) if len(b) else 0.0 for b in residual_b]    # logs' mean offset
        per_log_fit["per_log_bearing_offset_rad"] = own_offsets
        typical = float(np.mean(own_offsets))
        residual_b = [wrap_angle(b - o + typical) for b, o in zip(residual_b, own_offsets, strict=True)]
    fit = {"odometry_window_s": float(window_s), "odometry_windows": int(len(u)),
           **bias_fit, **lag_fit, **deficit_fit, **turn_fit, **time_fit, **stall_fit, **per_log_fit,
           "odometry_max_gap_s": float(max(np.max(np.diff(log.odometry[:, 0])) for log in logs))}
    if residual_r and sum(len(r) for r in residual_r) >= 20:
        dr, db, r = np.concatenate(residual_r), np.concatenate(residual_b), np.concatenate(ranges)
        offset = float(np.median(db))
        db = wrap_angle(db - offset)
        inlier = (np.abs(dr - np.median(dr)) < OUTLIER_MADS * _robust_sigma(dr)) & \
                 (np.abs(db) < OUTLIER_MADS * _robust_sigma(db))
        coefficients, _ = nnls(np.column_stack([np.ones(inlier.sum()), r[inlier]]),
                               np.abs(dr[inlier]) * math.sqrt(math.pi / 2))
        a, b = (float(c) for c in coefficients)
        if a <= 0:   # a σ that vanishes at r = 0 would make close sightings infinitely precise
            a = float(np.min(np.abs(dr[inlier]) * math.sqrt(math.pi / 2)) + 1e-3)
        # the footprint: where the sensor reported anything (extreme 0.1 % of the sightings left out)
        fov = float(min(2.0 * np.percentile(np.abs(wrap_angle(np.concatenate(bearings) - offset)), 99.9), 2 * math.pi))
        min_range, max_range = (float(v) for v in np.percentile(r, [0.1, 99.9]))
        # sightings j and next[j] are consecutive sightings of one landmark (within CORRELATION_GAP_S)
        shift = np.cumsum([0] + [len(x) for x in residual_r[:-1]])
        nxt = np.concatenate([np.where(f >= 0, f + s0, -1) for f, s0 in zip(follows, shift, strict=True)])
        pair = np.flatnonzero((nxt >= 0) & inlier)
        pair = pair[inlier[nxt[pair]]]
        rho_r = _lag_correlation(dr / (a + b * r), pair, nxt)
        rho_b = _lag_correlation(db, pair, nxt)
        inflation_r = _pass_inflation(dr / (a + b * r), nxt, inlier)
        inflation_b = _pass_inflation(db / float(np.sqrt(np.mean(db[inlier] ** 2))), nxt, inlier)
        fit.update(range_lag1_correlation=rho_r, bearing_lag1_correlation=rho_b,
                   range_pass_inflation=inflation_r, bearing_pass_inflation=inflation_b)
        if sensor_correlation == "passes":
            rho_r, rho_b = (float(np.clip((f - 1.0) / (f + 1.0), 0.0, 0.95)) for f in (inflation_r, inflation_b))
        range_bearing = RangeBearingNoise(range_sigma_m=a, range_sigma_per_m=b,
                                          bearing_sigma_rad=float(np.sqrt(np.mean(db[inlier] ** 2))),
                                          bearing_offset_rad=offset, fov_rad=fov, min_range_m=min_range,
                                          max_range_m=max_range, range_correlation=rho_r, bearing_correlation=rho_b,
                                          **dict(zip(_RANGE_CALIBRATION, range_fit, strict=True)))
        edges = [0.0] + [edge for _, edge in DETECTION_BANDS]
        for (label, _), lo, hi in zip(DETECTION_BANDS, edges[:-1], edges[1:], strict=True):
            probability = _detection_probability(logs, fov, lo, hi)
            if math.isfinite(probability):
                fit[f"detection_probability_{label}"] = probability
        fit["detection_correlation"] = _detection_correlation(logs, fov)
        fit.update(sightings=int(len(dr)), sensor_outlier_fraction=float(1.0 - inlier.mean()),
                   range_bias_median_m=float(np.median(dr[inlier])),
                   range_bias_below_2m_m=float(np.median(dr[inlier & (r < 2.0)])) if np.any(inlier & (r < 2.0))
                   else float("nan"),
                   range_residual_rms_m=float(np.sqrt(np.mean(dr[inlier] ** 2))))
        fit = {k: v for k, v in fit.items() if not (isinstance(v, float) and not math.isfinite(v))}
    name = robot or (logs[0].name if len(logs) == 1 else "+".join(log.name for log in logs))
    model = NoiseModel(
        OdometryNoise(q_xy, q_theta_rad, q_theta_m, translation_scale, rotation_scale, bias, lag, deficit, inflation,
                      theta_var_per_s=q_theta_s, stall_sigma_s=stall),
        range_bearing, None,
        robot=name, platform=platform, fit=fit,
        source=f"estimated by p3at slam noise from {', '.join(log.name for log in logs)} against its ground "
               f"truth ({len(u)} odometry windows of {window_s:g} s)")
    if heading_drift:
        model = _with_heading_drift(model, logs)
    return NoiseEstimate(model, np.array(by_window, float).reshape(-1, 4))


def _with_heading_drift(model: NoiseModel, logs: Sequence[RangeBearingLog]) -> NoiseModel:
    """``model`` with a drifting heading bias per metre (σ_b, τ) fitted to its dead reckoning over 5-600 s
    (``odometry_consistency.fit_heading_drift``: the grid whose NEES per horizon looks most like χ²₃), and the fit's
    costs in [fit]. σ_b = 0 (none) if no drift does better than none."""
    drift = fit_heading_drift([(log.odometry, log.ground_truth) for log in logs], model)
    odometry = replace(model.odometry, heading_drift_sigma_per_m=drift.sigma_per_m, heading_drift_tau_s=drift.tau_s)
    fit = {**model.fit, "heading_drift_cost": drift.cost, "heading_drift_cost_without": drift.cost_without}
    return replace(model, odometry=odometry, fit=fit)


_RANGE_CALIBRATION = ("range_offset_m", "range_scale", "range_scale_per_rad", "range_scale_per_rad2")
_NO_RANGE_CALIBRATION = (0.0, 1.0, 0.0, 0.0)   # a, b₀, b₁, b₂ of the identity


def _range_calibration(ranges: np.ndarray, bearings: np.ndarray, true_ranges: np.ndarray) -> tuple[float, ...]:
    """(a, b₀, b₁, b₂) of r_true ≈ a + r·(b₀ + b₁φ + b₂φ²) (measured r, φ (N,); see RangeBearingNoise.corrected):
    least squares, refitted three times on the sightings within OUTLIER_MADS robust σ of the last fit (misread
    barcodes and Vicon glitches must not bend it). The identity if the fit leaves b₀ outside [0.5, 2]."""
    design = np.column_stack([np.ones_like(ranges), ranges, ranges * bearings, ranges * bearings ** 2])
    keep = np.ones(len(ranges), bool)
    coefficients = np.array(_NO_RANGE_CALIBRATION)
    for _ in range(3):
        if keep.sum() < design.shape[1] * 5:
            break
        coefficients, *_ = np.linalg.lstsq(design[keep], true_ranges[keep], rcond=None)
        error = true_ranges - design @ coefficients
        keep = np.abs(error - np.median(error)) < OUTLIER_MADS * _robust_sigma(error)
    if not 0.5 <= coefficients[1] <= 2.0:
        return _NO_RANGE_CALIBRATION
    return tuple(float(c) for c in coefficients)


LAG_GRID_S = np.arange(0.0, 0.505, 0.01)   # candidate lags of the odometry behind the motion
LAG_STEP_S = 0.25                           # the step the lag is judged at: MRCLAM's frame interval (~4 Hz)
LAG_MIN_GAIN = 0.01   # a lag must lower the squared heading error by this fraction, or there is none to see


def _odometry_lag(logs: Sequence[RangeBearingLog]) -> tuple[float, dict]:
    """The time (s, on LAG_GRID_S) by which the odometry leads the motion, and the fit's figures: the lag whose
    odometry turns over LAG_STEP_S steps, each scaled by the least-squares rotation scale of that lag, have the
    smallest squared error against the true turns (pooled over the logs). A commanded-velocity odometry leads by
    the drive's actuation lag (MRCLAM: 0.16-0.20 s by cross-correlating the turn rates); encoders lead by ~0.
    A lag that lowers the error by less than LAG_MIN_GAIN is not fitted (0): where the turn rate does not vary
    (a circle at constant speeds) every lag fits alike, and the grid's minimum is rounding noise that would
    shift the whole odometry in time (MRCLAM: 20 % lower, so unaffected)."""
    pairs = []
    for log in logs:
        lo, hi = log.ground_truth[0, 0] + LAG_GRID_S[-1], log.ground_truth[-1, 0]
        lo, hi = max(lo, log.odometry[0, 0] + LAG_GRID_S[-1]), min(hi, log.odometry[-1, 0])
        if hi - lo > 10 * LAG_STEP_S:
            pairs.append((log, np.arange(lo, hi, LAG_STEP_S)))
    if not pairs:
        return 0.0, {}
    true_turn = np.concatenate([wrap_angle(np.diff(log.true_pose(t)[:, 2])) for log, t in pairs])
    errors = []
    for lag in LAG_GRID_S:
        turn = np.concatenate([between(p[:-1], p[1:])[:, 2] for p in (log.odometry_pose(t - lag) for log, t in pairs)])
        k = float(true_turn @ turn / max(turn @ turn, 1e-12))
        errors.append(float(np.mean(wrap_angle(k * turn - true_turn) ** 2)))
    best = int(np.argmin(errors))
    if errors[best] > (1.0 - LAG_MIN_GAIN) * errors[0]:
        return 0.0, {"odometry_lag_note": "not fitted: no lag lowers the heading error by "
                                          f"{100 * LAG_MIN_GAIN:g} % (the turn rate hardly varies)",
                     "odometry_no_lag_heading_rms_rad": float(np.sqrt(errors[0]))}
    return float(LAG_GRID_S[best]), {"odometry_lag_heading_rms_rad": float(np.sqrt(errors[best])),
                                     "odometry_no_lag_heading_rms_rad": float(np.sqrt(errors[0]))}


def _translation_calibration(logs, window_s: float, rotation_scale: float, bias: float, lag: float,
                             g: np.ndarray, turn_translation: bool) -> tuple[float, float, dict]:
    """(translation scale k, forward deficit per radian c, the fit's figures): with the turns calibrated, the
    windows' calibrated displacements u(c) scale linearly with k, so k(c) = Σ g·u / Σ u² (g the true ones) and
    the squared error left, S(c), is minimised over c in [0, MAX_FORWARD_DEFICIT_PER_RAD] (c = 0 unless
    ``turn_translation``). c's standard error: √(2σ² / S''(c)), σ² = S / (2W − 2) (W windows, x and y each)."""
    def profile(c: float) -> tuple[float, float]:
        u = np.concatenate([_odometry_windows(log, window_s, (1.0, 1.0, rotation_scale), bias, lag, c)[0]
                            for log in logs])[:, :2]
        k = float(np.sum(g[:, :2] * u) / max(np.sum(u ** 2), 1e-12))
        return k, float(np.sum((g[:, :2] - k * u) ** 2))

    k0, s0 = profile(0.0)
    if not turn_translation:
        return k0, 0.0, {}
    best = minimize_scalar(lambda c: profile(c)[1], bounds=(0.0, MAX_FORWARD_DEFICIT_PER_RAD), method="bounded",
                           options={"xatol": 1e-4})
    c = float(best.x) if best.fun < s0 else 0.0
    k, s = profile(c)
    if not 0.5 <= k <= 2.0:
        return k0, 0.0, {"forward_deficit_note": f"not fitted: the translation scale with it would be {k:.3f}"}
    h = 0.005
    lo, hi = max(c - h, 0.0), min(c + h, MAX_FORWARD_DEFICIT_PER_RAD)
    mid = 0.5 * (lo + hi)
    curvature = (profile(hi)[1] - 2.0 * profile(mid)[1] + profile(lo)[1]) / (0.5 * (hi - lo)) ** 2
    sigma2 = s / max(2 * len(g) - 2, 1)
    se = float(np.sqrt(2.0 * sigma2 / curvature)) if curvature > 0 else float("nan")
    fit = {"forward_deficit_translation_scale_alone": k0,
           "forward_deficit_displacement_rms_m": float(np.sqrt(s / max(len(g), 1))),
           "forward_deficit_none_displacement_rms_m": float(np.sqrt(s0 / max(len(g), 1)))}
    if math.isfinite(se):
        fit["forward_deficit_per_rad_standard_error"] = se
    return k, c, fit


def _calibrated(increments, scales, heading_bias_per_m: float, forward_deficit_per_rad: float = 0.0) -> np.ndarray:
    """Odometry increments (T, 3) scaled by ``scales`` (x, y, θ), plus the heading bias per metre of each
    increment's odometry distance (its chord: increments between frames and 50 Hz steps are short); with a
    forward deficit c, each increment's translation is first shortened by c·|Δθ| (its odometry turn) along its
    own direction, to no less than zero: d' = max(d − c·|Δθ|, 0). Why this form: MRCLAM's robots (iRobot Creates
    driven by commanded velocity) make 0.65 of the commanded distance in arcs of 0.38 rad/s and all of it going
    straight, and the deficit's rate follows |ω| at any speed (docs/fastslam-history.md "Session 16 (Q)"), so it is a
    distance per radian, which adds up the same over 50 Hz steps and 0.25 s frames; a turn on the spot, whose
    odometry distance is zero, keeps it zero (the clip)."""
    raw = np.asarray(increments, float).reshape(-1, 3)
    out = raw * np.asarray(scales, float)
    distance = np.hypot(raw[:, 0], raw[:, 1])
    if forward_deficit_per_rad != 0.0:
        keep = np.clip(1.0 - forward_deficit_per_rad * np.abs(raw[:, 2]) / np.maximum(distance, 1e-300), 0.0, 1.0)
        out[:, :2] *= keep[:, None]
    out[:, 2] += heading_bias_per_m * distance
    return out


def _heading_calibration(turn: np.ndarray, distance: np.ndarray | None, true_turn: np.ndarray):
    """(rotation scale k_r, heading bias c rad/m, c's standard error) by least squares over windows, true_turn ≈
    k_r·turn + c·distance (all (W,)); ``distance`` None: c = 0 (the scale alone, as before the bias existed).

    A robot that turns in proportion to the distance it drives (a circle at constant speeds) cannot tell a bias
    per metre from a rotation scale: when the two regressors are that collinear (variance inflation factor
    1/(1 − cos²) > MAX_VARIANCE_INFLATION, cos their uncentred correlation), or the joint fit puts c beyond
    MAX_HEADING_BIAS_PER_M, c = 0 and its standard error is NaN."""
    scale_only = float(np.sum(true_turn * turn) / max(np.sum(turn ** 2), 1e-12)), 0.0, float("nan")
    if distance is None:
        return scale_only
    cos = float(turn @ distance) / max(float(np.sqrt((turn @ turn) * (distance @ distance))), 1e-300)
    if not 1.0 - cos ** 2 > 1.0 / MAX_VARIANCE_INFLATION:
        return scale_only
    design = np.column_stack([turn, distance])
    (k_r, c), *_ = np.linalg.lstsq(design, true_turn, rcond=None)
    residual = true_turn - design @ [k_r, c]
    dof = max(len(turn) - 2, 1)
    covariance = np.linalg.pinv(design.T @ design) * float(residual @ residual) / dof
    if not (abs(c) <= MAX_HEADING_BIAS_PER_M and 0.5 <= k_r <= 2.0):
        return scale_only
    return float(k_r), float(c), float(np.sqrt(covariance[1, 1]))


def _turn_inflation(logs, scales, heading_bias_per_m, lag_s, forward_deficit_per_rad, q_xy):
    """The turns' overdispersion (see estimate_noise's ``turn_variance``) and its figures for ``fit``."""
    per_turn, increments = [], 0
    for log in logs:
        u, g, _ = _odometry_windows(log, TURN_STEP_S, scales, heading_bias_per_m, lag_s, forward_deficit_per_rad)
        if len(u) == 0:
            continue
        # σ of each increment's forward travel under the fitted random walk, as the filter moves particles by it
        sigma = np.sqrt(increment_variance(u, replace(FastSLAMConfig(), odom_xy_var_per_m=q_xy))[:, 0])
        z = (g[:, 0] - u[:, 0]) / sigma
        for start, stop in turn_spans(turning(u), TURN_MIN_INCREMENTS):
            per_turn.append(float(z[start:stop].sum() / np.sqrt(stop - start)))
            increments += stop - start
    if len(per_turn) < 3:
        return 1.0, {"turn_xy_inflation_note": f"not fitted: {len(per_turn)} turns of ≥ {TURN_MIN_INCREMENTS} "
                                                f"increments of {TURN_STEP_S:g} s"}
    square = float(np.mean(np.square(per_turn)))
    inflation = float(np.clip(square, 1.0, MAX_TURN_XY_INFLATION))
    return inflation, {"turn_xy_inflation_turns": len(per_turn), "turn_xy_inflation_increments": increments,
                       "turn_xy_inflation_mean_z_sum": float(np.mean(per_turn)),
                       "turn_xy_inflation_measured": square}


def _odometry_windows(log: RangeBearingLog, window_s: float, scales=(1.0, 1.0, 1.0), heading_bias_per_m=0.0,
                      lag_s: float = 0.0, forward_deficit_per_rad: float = 0.0, time_column: bool = False):
    """Consecutive windows of odometry rows inside the ground truth: odometry increments u (W, 3) calibrated by
    ``scales``, the heading bias per odometry metre and the forward deficit per radian, true increments g (W, 3)
    (``lag_s`` later than the odometry rows' times: the odometry leads the motion), and the design (W, K, 3, 3):
    the error covariance of each window is Σ_k q_k · design[:, k] for the model's variances
    q = (q_xy, q_θ/rad, q_θ/m), K = 3, and with ``time_column`` also q_θ/s, K = 4: each step's heading noise of
    variance q_θ/s × its duration (the window's duration over its steps: MRCLAM's stamps are coarser than its rows)
    (see _random_walk_fit)."""
    rows = log.odometry
    rows = rows[(rows[:, 0] >= log.ground_truth[0, 0]) & (rows[:, 0] <= log.ground_truth[-1, 0])]
    columns = 4 if time_column else 3
    empty = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, columns, 3, 3))
    if len(rows) < 3:
        return empty
    # the rows' interval: their median step, or, where most rows share a stamp (stamps coarser than the rows: MRCLAM's
    # copy stamps its 50 Hz rows to 0.1 s from t = 1000 s on, so the median step there is 0), the mean step
    step_s = float(np.median(np.diff(rows[:, 0])))
    if not step_s > 0:
        step_s = float(rows[-1, 0] - rows[0, 0]) / (len(rows) - 1)
    n = max(1, int(round(window_s / max(step_s, 1e-9))))
    k = (len(rows) - 1) // n
    if k < 1:
        return empty
    rows = rows[: k * n + 1]
    steps = _calibrated(between(rows[:-1, 1:], rows[1:, 1:]), scales, heading_bias_per_m,   # robot frame
                        forward_deficit_per_rad)
    # the calibrated chain, in closed form: heading before step j, then positions after each step
    heading = np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    xy = np.vstack([[0.0, 0.0], np.cumsum(np.column_stack([c * steps[:, 0] - s * steps[:, 1],
                                                             s * steps[:, 0] + c * steps[:, 1]]), axis=0)])
    chain = np.column_stack([xy, heading])                     # (k·n + 1, 3), θ unwrapped
    window = np.arange(k * n) // n
    starts = chain[0:k * n:n]
    u = between(starts, chain[n::n])
    u[:, 2] = chain[n::n, 2] - starts[:, 2]                    # the turn itself, not wrapped
    g = between(log.true_pose(rows[0:k * n:n, 0] + lag_s), log.true_pose(rows[n::n, 0] + lag_s))
    g[:, 2] = u[:, 2] + wrap_angle(g[:, 2] - u[:, 2])          # the true turn nearest the odometry's (no 2π jumps)
    # first-order effect on the window's end pose of a noise δ on step j (robot frame at the step's start):
    # the end moves by R(θ_{j-1}) δ_xy + δ_θ v_j, v_j = (−(y_end − y_j), x_end − x_j, 1) in the window's frame
    after = between(starts[window], chain[1:])
    end = u[window]
    v = np.column_stack([-(end[:, 1] - after[:, 1]), end[:, 0] - after[:, 0], np.ones(k * n)])
    distance = np.hypot(steps[:, 0], steps[:, 1])
    turn = np.abs(steps[:, 2])
    outer = v[:, :, None] * v[:, None, :]
    design = np.zeros((k, columns, 3, 3))
    seconds = ((rows[n::n, 0] - rows[0:k * n:n, 0]) / n)[window] if time_column else None
    for a in range(3):
        for b in range(3):
            design[:, 1, a, b] = np.bincount(window, turn * outer[:, a, b], minlength=k)
            design[:, 2, a, b] = np.bincount(window, distance * outer[:, a, b], minlength=k)
            if time_column:
                design[:, 3, a, b] = np.bincount(window, seconds * outer[:, a, b], minlength=k)
    design[:, 0, 0, 0] = design[:, 0, 1, 1] = np.bincount(window, distance, minlength=k)
    return u, g, design


def _random_walk_fit(windows) -> tuple[float, ...]:
    """(q_xy, q_θ/rad, q_θ/m) ≥ 0 (and q_θ/s, if the windows' design has the time column) matching each window's
    e eᵀ (e = g − u) to its modelled covariance, element by element (xx, yy, θθ, xy, xθ, yθ), by non-negative least
    squares with each element's equations scaled to unit spread (metres and radians mixed)."""
    e = np.concatenate([w[1] - w[0] for w in windows])
    design = np.concatenate([w[2] for w in windows])
    lhs, rhs = [], []
    for a, b in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)):
        y = e[:, a] * e[:, b]
        spread = float(np.std(y)) or 1.0
        lhs.append(design[:, :, a, b] / spread)
        rhs.append(y / spread)
    q, _ = nnls(np.concatenate(lhs), np.concatenate(rhs))
    return tuple(float(v) for v in q)


CORRELATION_GAP_S = 2.0     # consecutive sightings of one landmark further apart than this are not paired


def _consecutive(times: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(N,) index of the next sighting of the same landmark within CORRELATION_GAP_S, or -1."""
    out = np.full(len(times), -1, np.int64)
    order = np.lexsort((times, ids))
    same = (ids[order][1:] == ids[order][:-1]) & (np.diff(times[order]) <= CORRELATION_GAP_S)
    out[order[:-1][same]] = order[1:][same]
    return out


def _pass_inflation(residuals: np.ndarray, nxt: np.ndarray, inlier: np.ndarray) -> float:
    """The variance inflation f a filter needs over whole passes, from residuals (N,) in units of their σ.

    A pass is a chain of consecutive sightings of one landmark (``nxt``: the next one within CORRELATION_GAP_S,
    -1 at a chain's end); its inliers' mean m over n sightings has the variance f/n if each sighting's variance
    is taken as f (σ² = 1) and the sightings as independent, which is what the filter does. So f is estimated as
    the mean of n·m² over the passes of at least 2 inliers (1 if there are fewer than 20 passes). Unlike the
    lag-1 correlation's AR(1), this also counts the error a pass shares throughout (a landmark's geometry).
    """
    has_previous = np.zeros(len(nxt), bool)
    has_previous[nxt[nxt >= 0]] = True
    values = []
    for start in np.flatnonzero(~has_previous):
        chain, j = [], int(start)
        while j >= 0:
            if inlier[j]:
                chain.append(j)
            j = int(nxt[j])
        if len(chain) >= 2:
            values.append(len(chain) * float(np.mean(residuals[chain])) ** 2)
    return float(max(np.mean(values), 1.0)) if len(values) >= 20 else 1.0


def _lag_correlation(residuals: np.ndarray, pair: np.ndarray, nxt: np.ndarray) -> float:
    """Correlation of residual j with residual next[j] over the pairs (0 if fewer than 20), clipped to [0, 0.95]."""
    if len(pair) < 20:
        return 0.0
    x, y = residuals[pair], residuals[nxt[pair]]
    x, y = x - residuals.mean(), y - residuals.mean()
    rho = float(np.sum(x * y) / max(np.sqrt(np.sum(x * x) * np.sum(y * y)), 1e-300))
    return float(np.clip(rho, 0.0, 0.95))


def _detection_frames(log: RangeBearingLog, fov: float, near: float, far: float, margin: float = 0.85):
    """Per frame (distinct sighting time) and true landmark: in view (``margin`` of the half field of view, range
    in [near, far)) at the true pose, and reported; both (F, L) bool, with the frame times (F,)."""
    times, frame = np.unique(log.sighting_times, return_inverse=True)
    pose = log.true_pose(times)
    d = log.truth_positions[None, :, :] - pose[:, None, :2]
    r = np.hypot(d[..., 0], d[..., 1])
    b = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - pose[:, 2:3])
    in_view = (np.abs(b) < margin * fov / 2) & (r >= near) & (r < far)
    seen = np.zeros_like(in_view)
    known = np.isin(log.landmark_ids, log.truth_ids)
    seen[frame[known], np.searchsorted(log.truth_ids, log.landmark_ids[known])] = True
    return in_view, seen, times


def _usable(log: RangeBearingLog) -> bool:
    return len(log) > 0 and len(log.truth_ids) > 0


def _detection_probability(logs: Sequence[RangeBearingLog], fov: float, near: float, far: float) -> float:
    """P(a landmark well inside the view at a range in [near, far) is reported in a frame), over the frames
    (distinct sighting times) of the logs, from the true poses."""
    hits = total = 0
    for log in filter(_usable, logs):
        in_view, seen, _ = _detection_frames(log, fov, near, far)
        hits += int((seen & in_view).sum())
        total += int(in_view.sum())
    return hits / total if total else float("nan")


def _detection_correlation(logs: Sequence[RangeBearingLog], fov: float) -> float:
    """Lag-1 correlation of a landmark's reported / not reported indicator over consecutive frames (at most
    CORRELATION_GAP_S apart) in which it is well in view at the true pose; clipped to [0, 0.95]."""
    x, y = [], []
    for log in filter(_usable, logs):
        in_view, seen, times = _detection_frames(log, fov, 0.0, math.inf)
        pair = (np.diff(times) <= CORRELATION_GAP_S)[:, None] & in_view[:-1] & in_view[1:]
        x.append(seen[:-1][pair])
        y.append(seen[1:][pair])
    x, y = (np.concatenate(v).astype(float) if v else np.zeros(0) for v in (x, y))
    if len(x) < 20 or x.std() == 0 or y.std() == 0:
        return 0.0
    return float(np.clip(np.corrcoef(x, y)[0, 1], 0.0, 0.95))


def _robust_sigma(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) + 1e-12


def with_fastslam(model: NoiseModel, config):
    """``config`` (a FastSLAMConfig) with the model's motion noise, the sensor's footprint and, when the model
    carries them, its detection rates for the landmarks' existence (:meth:`NoiseModel.existence_overrides`)."""
    return replace(config, **model.fastslam_overrides(), **model.existence_overrides())


def increment_variances(log: RangeBearingLog, noise: NoiseModel, config, frame_times, increments) -> np.ndarray:
    """The variances (T, 3) of (dx, dy, dθ) of ``log``'s calibrated odometry ``increments`` (T, 3) between consecutive
    ``frame_times`` (T + 1,): the random walk's (:func:`~estimation.fastslam.motion.increment_variance` with
    ``config``, a FastSLAMConfig that has the model's keys, :func:`with_fastslam`) plus the model's stalls after the
    command's dips if it has that term (:func:`~estimation.odometry_stall.command_stall_variance`). The odometry
    factors of every smoother of a log: the data set's (``estimation.dataset_smoothing``), the camera's
    self-calibration, the chain's named smoothing and its path variances. (The data set's filter takes the stall's
    variances apart: its predict adds them to its own random walk, ``estimation.dataset_slam``.)"""
    variances = increment_variance(increments, config, np.diff(frame_times))
    if (stalls := command_stall_variance(log.velocities, noise, frame_times)) is not None:
        variances = variances + stalls
    return variances
