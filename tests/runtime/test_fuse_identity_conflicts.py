"""`p3at fuse` on known-ID maps that disagree about one identity: the merged map holds it once, and the command
says which robot put it where (text warning and --json)."""
from __future__ import annotations

import contextlib
import io
import json

import numpy as np

from estimation.geometry import inverse, transform_points
from estimation.landmark_map import LandmarkMap
from runtime.cli import main

FRAMES = [(0.0, 0.0, 0.0), (3.0, 1.0, 0.5), (-2.0, 4.0, -1.0)]


def _maps(tmp_path, displaced: float) -> list[str]:
    """Three maps of 30 identified posts (σ 0.03 m, claiming 0.05 m); robot3 puts post 7 ``displaced`` m off."""
    rng = np.random.default_rng(0)
    world = np.column_stack([np.stack(np.meshgrid(np.arange(6) * 2.5, np.arange(5) * 2.0), -1).reshape(-1, 2)
                             + rng.uniform(-0.5, 0.5, (30, 2)), np.zeros(30)])
    paths = []
    for k, frame in enumerate(FRAMES):
        local = transform_points(inverse(np.asarray(frame, float)), world)
        local[:, :2] += rng.standard_normal((30, 2)) * 0.03
        if k == 2:
            local[7, :2] += displaced * np.array([0.6, 0.8])
        cov = np.repeat(np.diag([0.05 ** 2, 0.05 ** 2, 1e-6])[None], 30, 0)
        path = tmp_path / f"robot{k + 1}.npz"
        LandmarkMap(local, cov, np.zeros((30, 0), np.float32), robot=f"robot{k + 1}",
                    metadata={"external_ids": list(range(30))}).save(path)
        paths.append(str(path))
    return paths


def _fuse(*argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(["fuse", *argv])
    return status, out.getvalue(), err.getvalue()


def test_fuse_names_the_robot_whose_landmark_disagrees(tmp_path):
    status, out, err = _fuse(*_maps(tmp_path, 1.5), "--out", str(tmp_path / "merged.npz"), "--json")
    assert status == 0
    report = json.loads(out)
    assert [(c["identity"], c["robot"]) for c in report["identity_conflicts"]] == [(7, "robot3")]
    assert report["merged_landmarks"] == 30                                 # the post once, not twice
    warnings = [line for line in err.splitlines() if "identity 7" in line]
    assert len(warnings) == 1 and "robot3" in warnings[0] and "warning" in warnings[0]
    assert LandmarkMap.load(tmp_path / "merged.npz").metadata["identity_conflicts"][0]["identity"] == 7


def test_fuse_of_maps_that_agree_reports_no_conflict(tmp_path):
    status, out, err = _fuse(*_maps(tmp_path, 0.0), "--out", str(tmp_path / "merged.npz"), "--json")
    assert status == 0 and json.loads(out)["identity_conflicts"] == [] and "identity" not in err
