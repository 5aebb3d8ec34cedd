"""The visual front end: Harris corners, U-SURF descriptors, stereo matching, triangulation with covariance.

Typical use (the runtime builds the geometry from the head's calibration)::

    front_end = FrontEnd(FrontEndConfig(geometry=StereoGeometry(fx=520, fy=520, cx=319.5, cy=239.5,
                                                                baseline=0.09)))
    observations = front_end.process(left_rectified, right_rectified, timestamp)
"""
from __future__ import annotations

from estimation.frontend.buffers import ScratchBuffers
from estimation.frontend.descriptors import DescriptorKind, describe, distance_matrix
from estimation.frontend.errors import FrontEndError
from estimation.frontend.harris import HarrisConfig, detect_corners, harris_response
from estimation.frontend.pipeline import (
    FrontEnd,
    FrontEndConfig,
    RectificationMaps,
    StereoMatches,
    rectify_pair,
    run_frontend,
)
from estimation.frontend.stereo import StereoMatchConfig, match_rows, refine_disparity_ssd
from estimation.frontend.triangulation import (
    StereoGeometry,
    TriangulationNoise,
    camera_to_base,
    triangulate,
    triangulation_covariances,
)
from estimation.frontend.usurf import integral_image, usurf_descriptors

__all__ = [
    "DescriptorKind", "FrontEnd", "FrontEndConfig", "FrontEndError", "HarrisConfig", "RectificationMaps",
    "ScratchBuffers", "StereoGeometry", "StereoMatchConfig", "StereoMatches", "TriangulationNoise", "camera_to_base",
    "describe",
    "detect_corners", "distance_matrix", "harris_response", "integral_image", "match_rows", "rectify_pair",
    "refine_disparity_ssd", "run_frontend", "triangulate", "triangulation_covariances", "usurf_descriptors",
]
