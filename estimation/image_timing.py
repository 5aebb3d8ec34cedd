"""One bearing error per image from its time stamp: the σ τ_k of the error all the sightings of image k share.

A range-bearing log stamps each image's readings at one time t_k. The camera exposed the image at some instant near
it that the log does not give, and a robot turning at ω_k sees every landmark of that image turned by the same
ω_k δ, δ the exposure's offset from the stamp. So the bearings of one image share an error of σ |ω_k| σ_t, σ_t the
stamp's timing uncertainty; the smoother holds it as a joint covariance of the image's bearings
(:func:`estimation.landmark_smoother.image_whitening`).

σ_t is derived, not fitted: the log stamps images on its own ticks, one period P apart (the median interval between
two consecutive stamps: on MRCLAM 0.24 s, the camera's ~4 Hz), and nothing in it says where within a period the
exposure fell, so δ is taken uniform over one period: variance P² / 12, σ_t = P / √12 (0.069 s on MRCLAM). A mean
offset of the camera against the odometry is a calibration (like the odometry's ``lag_s``), not this variance, and
is not modelled here. Checked against the truth, not fitted on it (docs/fastslam-history.md, session 47 (S)): on
MRCLAM the covariance of two bearing errors of one image grows with ω² as a σ_t of 0.05–0.08 s (robots 2, 3, 5; robot
1's truth heading wanders, robot 4 has few images with two sightings while turning), and session 41 (A) had read
the bearings' excess variance while turning as a jitter of ~0.065 s.

Why not the odometry's stall after a dip of the command (``stall_sigma_s``, 0.09 s): that is the robot's motion
lagging its command, already on the odometry increments that hold a dip (:mod:`estimation.odometry_stall`); it
moves the pose, not the image's time.

ω_k is the odometry's (calibrated: its rotation scale, and its lag: :meth:`NoiseModel.odometry_times`), the turn
over the period centred on the stamp, so that the turn the exposure may have missed is the one used; no truth is
read.
"""
from __future__ import annotations

import numpy as np

from .datasets import RangeBearingLog
from .geometry import wrap_angle
from .noise_model import NoiseModel


def stamp_period(times: np.ndarray) -> float:
    """P (s): the median interval between consecutive distinct stamps of ``times`` (N,) (a log's sightings), the
    period the log stamps its images on; NaN with fewer than two distinct stamps."""
    steps = np.diff(np.unique(np.asarray(times, float)))
    return float(np.median(steps)) if len(steps) else float("nan")


def timing_sigma(period_s: float) -> float:
    """σ_t (s) of an exposure uniform over one stamp period P: P / √12."""
    return float(period_s) / np.sqrt(12.0)


def turn_rates(log: RangeBearingLog, noise: NoiseModel, times: np.ndarray, period_s: float) -> np.ndarray:
    """ω (T,) rad/s at ``times`` (T,): the calibrated odometry's turn over [t − P/2, t + P/2] / P (the odometry read
    at its own times, t − ``lag_s``; scaled by its ``rotation_scale``)."""
    times = np.asarray(times, float)
    if not len(times):
        return np.zeros(0)
    half = 0.5 * float(period_s)
    before = log.odometry_pose(noise.odometry_times(times - half))[:, 2]
    after = log.odometry_pose(noise.odometry_times(times + half))[:, 2]
    return noise.odometry.rotation_scale * wrap_angle(after - before) / (2.0 * half)


def image_bearing_sigmas(log: RangeBearingLog, noise: NoiseModel, times: np.ndarray) -> tuple[np.ndarray, float]:
    """(τ (T,) rad: |ω_k| σ_t for the images stamped ``times`` (T,), σ_t (s)), σ_t from the log's own stamp period
    (:func:`stamp_period`, :func:`timing_sigma`). A log with fewer than two stamps: no term (τ 0, σ_t 0)."""
    period = stamp_period(log.sighting_times)
    if not np.isfinite(period) or period <= 0:
        return np.zeros(len(times)), 0.0
    sigma_t = timing_sigma(period)
    return np.abs(turn_rates(log, noise, times, period)) * sigma_t, sigma_t
