"""2-D range-bearing landmark observations (the classic landmark datasets) as FastSLAM observations.

A measurement (r, φ) with standard deviations (σ_r, σ_φ) becomes the planar point p = (r cos φ, r sin φ, 0)
with the first-order covariance J diag(σ_r², σ_φ²) Jᵀ, J = ∂p/∂(r, φ) = [[cos φ, −r sin φ], [sin φ, r cos φ]],
and a tiny vertical variance that pins landmarks to z = 0. For a planar landmark the filter's point model
z = Rᵀ(m − t) is then the range-bearing model h(m, x) = (‖m − t‖, atan2(·) − θ) composed with this
(invertible) polar-to-Cartesian change of variables, linearised at the measurement rather than at the
prediction; the difference is second order in σ_φ and negligible for the usual σ_φ ≲ 3°.
"""
from __future__ import annotations

import numpy as np

from ..observations import StereoObservations

_Z_VARIANCE = 1e-6  # m²: keeps the landmark's vertical coordinate at 0 without a singular covariance


def range_bearing_observations(ranges, bearings, sigma_range: float | np.ndarray, sigma_bearing: float,
                               descriptors: np.ndarray | None = None, timestamp: float = 0.0,
                               ids=None) -> StereoObservations:
    """Observations (N points in base_link) from ranges (N,) m and bearings (N,) rad (counter-clockwise from x).
    ``sigma_range``: one σ_r (m) for all, or each measurement's (N,).

    descriptors (N, D) optional (default: none, D = 0, so association is by position alone; use
    :func:`~estimation.fastslam.range_bearing_config`); ids (N,) optional: the landmark identity each
    measurement reports (barcode, tag; -1 none), used by ``association="id"``.
    """
    r = np.asarray(ranges, float).reshape(-1)
    phi = np.asarray(bearings, float).reshape(-1)
    if r.shape != phi.shape:
        raise ValueError(f"{len(r)} ranges but {len(phi)} bearings")
    c, s = np.cos(phi), np.sin(phi)
    points = np.stack([r * c, r * s, np.zeros_like(r)], axis=1)
    jac = np.zeros((len(r), 3, 2))
    jac[:, 0, 0], jac[:, 0, 1] = c, -r * s
    jac[:, 1, 0], jac[:, 1, 1] = s, r * c
    if np.ndim(sigma_range) == 0:
        cov = np.einsum("nij,j,nkj->nik", jac, np.array([sigma_range ** 2, sigma_bearing ** 2]), jac)
    else:   # each row's own σ_r: the same products, row by row, as N calls with one σ_r each
        sigma_range = np.asarray(sigma_range, float).reshape(-1)
        if sigma_range.shape != r.shape:
            raise ValueError(f"{len(sigma_range)} range sigmas for {len(r)} measurements")
        # squared as Python floats, as one call with a float σ_r squares it (C's pow, which here differs from
        # numpy's x·x in the last bit for some σ)
        variances = np.array([(float(sigma) ** 2, sigma_bearing ** 2) for sigma in sigma_range]).reshape(-1, 2)
        cov = np.einsum("nij,nj,nkj->nik", jac, variances, jac)
    cov[:, 2, 2] = _Z_VARIANCE
    if descriptors is None:
        descriptors = np.zeros((len(r), 0), np.float32)
    if ids is not None:
        ids = np.asarray(ids).reshape(-1)
        if ids.shape != r.shape:
            raise ValueError(f"{len(ids)} ids for {len(r)} measurements")
    return StereoObservations(points, cov, np.asarray(descriptors, np.float32), np.zeros((0, 2)), timestamp,
                              ids=ids)
