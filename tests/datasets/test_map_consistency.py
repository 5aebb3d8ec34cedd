"""benchmarks/mrclam_constellation.map_consistency (session 30): the final record's joint NEES beside the
per-landmark figure. MRCLAM robot 2's first 300 s named by the barcodes (a right map) against the same with one visit
of post 17 named 16 (a wrong one); the barcodes only score."""
from __future__ import annotations

import numpy as np

from .test_constellation import _robot2
from .test_name_unnamed import _state


def test_the_joint_nees_passes_a_right_map_and_refuses_a_map_with_one_visit_under_the_wrong_name():
    from benchmarks.mrclam_constellation import map_consistency
    log, noise, config, drift = _robot2(until=300.0)
    honest = np.asarray(log.landmark_ids, np.int64)
    right = map_consistency(log, _state(log, honest, noise, config, drift))
    assert right["landmark_joint_dof"] == 2 * len(np.unique(honest[honest >= 0]))    # every name has its post
    assert right["landmark_joint_p"] > 0.01                # measured 0.07 (42.1 on 30)
    assert 0.0 < right["nees_figure_p_fail"] < 0.5         # a shared frame error: the figure fails by chance
    t = log.sighting_times - log.sighting_times[0]
    names = honest.copy()
    names[(honest == 17) & (t > 220.0) & (t < 232.0)] = 16            # a visit of post 17, 1.5 m from 16
    wrong = map_consistency(log, _state(log, names, noise, config, drift))
    assert wrong["landmark_joint_p"] < 1e-6                # measured: joint NEES 15,776 on 30
