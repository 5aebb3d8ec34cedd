"""Where a map's landmarks go in the merged map: the placement of a map's *shape*, not of its start frame.

An alignment answers "where is robot j's start frame in robot i's": ``refine_pose`` weighs each support by the maps'
claimed covariances, and a FastSLAM map claims its start-frame error (``mixture+drift``: the drift of the pose when a
landmark was made), so the landmarks mapped near the start, which claim least, set the pose.  That is the right
estimate of the start frames (MRCLAM, calibrated maps of seed 0: 0.215 m / 0.052 rad median against Vicon, against
0.284 m / 0.065 rad for an unweighted fit of the same supports; docs/fusion-history.md, "Session 9").

Merging asks another question: where do map j's landmarks best lie on map i's?  Once ``fusion.multi`` has calibrated
the maps (``covariance_scales``: each map's scatter about a rigid placement, σ_k² per axis, from the pairwise
residuals), the merge's own model of a map is "its landmarks scatter σ_k about a rigid placement", and the maximum
likelihood placement under that model is the least-squares fit of the supports under the *calibrated* covariances
(with the isotropic calibration: the plain Kabsch fit).  Placing each map by the alignment's start-frame pose put
the calibrated MRCLAM maps 0.06–0.20 m off where their own shapes fit (docs/fusion-history.md, "Session 9"), which is an
error every landmark of that map carries into the merge.
"""
from __future__ import annotations

import numpy as np

from estimation.landmark_map import LandmarkMap

from .ransac import refine_pose


def shape_placement(parent: LandmarkMap, child: LandmarkMap, supports: np.ndarray, pose
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The pose (3,) of ``child``'s frame in ``parent``'s that best fits the child's supports onto the parent's under
    both maps' covariances as they are given (calibrated ones, in ``fusion.multi``), and its covariance (3, 3)
    (inflated by the reduced χ² when above 1).  ``supports`` (K, 2) rows (parent, child), one-to-one; ``pose`` the
    start (the alignment's).  Fewer than two supports fix no pose: ``pose`` is returned with a zero covariance."""
    supports = np.asarray(supports, np.int64).reshape(-1, 2)
    if len(supports) < 2:
        return np.asarray(pose, float).copy(), np.zeros((3, 3))
    i, j = supports[:, 0], supports[:, 1]
    placed, covariance, _ = refine_pose(parent.positions[i], parent.covariances[i], child.positions[j],
                                        child.covariances[j], pose)
    return placed, covariance

