"""Three or more maps through ``runtime.fusion_report.fuse_maps`` (the mission's and the fleet node's fusion): the
report's ``seconds`` is the time the fusion took. The tree branch reused the name of the clock's start for each
pair's start covariance, so ``seconds`` came out as a (3, 3) array, and ``p3at demo --robots 3`` (as docs/runtime.md
shows it) ended in "internal error: TypeError: type numpy.ndarray doesn't define __round__ method" (exit 70)."""
from __future__ import annotations

import json
import time

import numpy as np

from runtime.fusion_report import fuse_maps


def test_three_maps_fused_report_the_time_taken_as_seconds(sim):
    maps = {robot: sim.building_map(robot, seed=0).map for robot in ("robot1", "robot2", "robot3")}
    before = time.perf_counter()
    report = fuse_maps(maps, rng=np.random.default_rng(0))
    took = time.perf_counter() - before
    assert [p.aligned for p in report.pairs] == [True, True]
    assert any(p.start_sigma_xy is not None for p in report.pairs)  # the branch that shadowed the clock ran
    assert isinstance(report.seconds, float) and 0.0 <= report.seconds <= took
    summary = json.loads(json.dumps(report.as_dict()))
    assert summary["seconds"] == report.seconds and summary["merged_landmarks"] == len(report.merged)
