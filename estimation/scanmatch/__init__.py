"""2-D scan matching: the extended ICP (eICP) of Armesto et al. with ICP and PL-ICP baselines.

Public API::

    match_scans(reference: Scan2D, current: Scan2D, method="eicp"|"eicp-mesh"|"icp"|"plicp",
                initial=(x, y, θ), config=MatchConfig()) -> MatchResult
    laser_scan(ranges, angles) / sonar_scan(odometry_poses, sonar_poses, ranges) -> Scan2D
    read_laser_log(path) -> list[LaserReading]          (CARMEN FLASER lines, .gz or plain)
    eicp_cost(reference, current, pose) -> float        (the eICP objective, λ at its optimum)
    apply_pose(pose, points (N, 2)) -> (N, 2)            (R(θ) p + t)
"""
from __future__ import annotations

from estimation.scanmatch.carmen import LaserReading, iter_laser, parse_flaser, read_laser_log
from estimation.scanmatch.common import MatchConfig, MatchResult, apply_pose
from estimation.scanmatch.eicp import eicp_cost
from estimation.scanmatch.errors import LogFormatError, ScanMatchError
from estimation.scanmatch.match import METHODS, match_scans
from estimation.scanmatch.polyline import Polyline
from estimation.scanmatch.scan import Scan2D, laser_angles, laser_scan, sonar_scan

__all__ = [
    "METHODS", "LaserReading", "apply_pose", "LogFormatError", "MatchConfig", "MatchResult", "Polyline", "Scan2D",
    "ScanMatchError", "eicp_cost", "iter_laser", "laser_angles", "laser_scan", "match_scans", "parse_flaser",
    "read_laser_log", "sonar_scan",
]
