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

This module holds the model: its sections (:class:`OdometryNoise`, :class:`RangeBearingNoise`, :class:`StereoNoise`),
:class:`NoiseModel` with the file's reading, writing and checks and the odometry's calibration, what hands a model
to the filter and the smoothers (:func:`with_fastslam`, :func:`increment_variances`), and the defaults for a P3-AT on
its wheels with the Videre head: :data:`P3AT_VIDERE_DEFAULT`, with its provenance in ``source``. Fitting a model
from logs with ground truth (``p3at slam noise``) is :mod:`estimation.noise_estimation`
(:func:`~estimation.noise_estimation.estimate_noise`).
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from .datasets import RangeBearingLog
from .errors import EstimationError
from .fastslam.motion import increment_variance
from .fileio import InputTooLargeError, atomic_write_bytes, read_bounded, special_file_kind
from .odometry_stall import MAX_STALL_SIGMA_S, command_stall_variance

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
        for name, section in (("odometry", self.odometry), ("range_bearing", self.range_bearing),
                              ("stereo", self.stereo)):
            if section is None:
                continue
            for f in fields(section):
                value = getattr(section, f.name)
                signed = f.name in SIGNED_FIELDS
                if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value) \
                        or (not signed and value < 0):
                    raise NoiseModelError(f"[{name}] {f.name} must be a finite number{'' if signed else ' >= 0'}, "
                                          f"not {value!r}")
                bound = MAGNITUDE_BOUNDS.get(f.name)
                if bound is not None and abs(value) > bound:
                    raise NoiseModelError(f"[{name}] {f.name} must lie within {'±' if signed else '[0, '}{bound:g}"
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


# -- defaults ------------------------------------------------------------------------------------------------
P3AT_VIDERE_DEFAULT = NoiseModel(
    odometry=OdometryNoise(xy_var_per_m=0.03 ** 2, theta_var_per_rad=0.05 ** 2, theta_var_per_m=0.02 ** 2),
    stereo=StereoNoise(sigma_u_px=0.5, sigma_v_px=0.5, sigma_d_px=0.3),
    robot="p3at", platform="Pioneer P3-AT (skid steer, wheel encoders) with a Videre STH-MDCS2 head",
    source="NOT measured: no P3-AT log with ground truth is available to this project. Odometry: the values "
           "FastSLAMConfig has always used (shared/reference gives encoder and geometry facts, no error figures); "
           "stereo: the front end's TriangulationNoise. Replace them with `p3at slam noise` on a log of your robot.",
)


# -- the model in the filter and the smoothers -------------------------------------------------------------
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
