"""benchmarks/mrclam_constellation --out-maps: the chain's final state written as a landmark map without
descriptors or identities, which ``p3at fuse`` aligns by geometry alone. The barcodes stand for a right chain's names
(MRCLAM robots 2 and 3); they only score, and stay out of the file."""
from __future__ import annotations

import contextlib
import io
import json

import numpy as np

from .test_constellation import _robot2
from .test_name_unnamed import _state

FULL_S = 1e9      # the whole log: two 300 s maps are too loose to beat chance by geometry alone (16 supports needed)


def _barcode_state(robot: int, until: float):
    from estimation.datasets import read_mrclam

    from .conftest import MRCLAM2
    log, noise, config, drift = _robot2(until)                # (skips when the data set is absent)
    if robot != 2:
        log = read_mrclam(MRCLAM2, robot, until=until)
    return log, _state(log, np.asarray(log.landmark_ids, np.int64), noise, config, drift)


def test_a_chain_map_carries_no_identity_and_its_frame_is_the_true_pose_at_its_first_named_sighting(tmp_path):
    from benchmarks.mrclam_constellation import chain_map
    from estimation.landmark_map import LandmarkMap
    from fusion.ransac import has_descriptors, landmark_identities
    log, state = _barcode_state(2, 300.0)
    path = tmp_path / "robot2.npz"
    chain_map(log, state).save(path)
    m = LandmarkMap.load(path)
    assert len(m) == len(np.unique(log.landmark_ids[state.named.sightings]))
    assert not has_descriptors(m) and landmark_identities(m) is None
    first = state.named.frame_times[0]
    np.testing.assert_allclose(m.metadata["true_start_pose"], log.true_pose([first])[0])
    np.testing.assert_allclose(m.trajectory[0, 1:], 0.0, atol=1e-6)     # the frame: the pose at the first frame
    assert m.trajectory[0, 0] == first and np.all(np.diff(m.trajectory[:, 0]) >= 0)
    assert np.allclose(m.positions[:, 2], 0.0) and np.all(np.linalg.eigvalsh(m.covariances[:, :2, :2]) > 0)


def test_two_chain_maps_are_aligned_by_geometry_alone_within_the_figure_against_vicon(tmp_path):
    from benchmarks.mrclam_constellation import chain_map
    from runtime.cli import main as p3at
    files = []
    for robot in (2, 3):
        log, state = _barcode_state(robot, FULL_S)
        files.append(tmp_path / f"robot{robot}.npz")
        chain_map(log, state).save(files[-1])
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = p3at(["fuse", *map(str, files), "--out", str(tmp_path / "merged.npz"), "--json", "--seed", "0"])
    report = json.loads(out.getvalue())
    (alignment,) = report["alignments"]
    assert code == 0 and alignment["found"], alignment.get("reason")
    assert alignment["error_xy"] <= 0.3 and alignment["error_theta"] <= 0.05
