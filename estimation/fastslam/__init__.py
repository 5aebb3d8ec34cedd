"""FastSLAM 1.0/2.0 over 3-D point landmarks with unknown data association (see ``filter.py``).

    from estimation.fastslam import FastSLAM, FastSLAMConfig
    slam = FastSLAM(FastSLAMConfig(n_particles=100), np.random.default_rng(seed))
    slam.predict(increment)            # OdometryIncrement
    report = slam.update(observations) # StereoObservations in base_link
    slam.best_pose(); slam.best_map(robot="robot1", metadata={...}).save(path)
"""
from __future__ import annotations

from .config import FastSLAMConfig, range_bearing_config
from .filter import FastSLAM, FilterStats, UpdateReport
from .range_bearing import range_bearing_observations
from .resampling import effective_sample_size, low_variance_resample, normalise_log_weights

__all__ = [
    "FastSLAM", "FastSLAMConfig", "FilterStats", "UpdateReport", "effective_sample_size", "low_variance_resample",
    "normalise_log_weights", "range_bearing_config", "range_bearing_observations",
]
