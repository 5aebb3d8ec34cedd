"""Outputs that would destroy what is there (session 25, C): refused in one line, exit 2, before any work, and the
input left as it was. Before, `replay LOG.mcap --out LOG.mcap` replaced the sensor log with a map, `features L R
--out L` the left image with a CSV, `slam simulate --out m.npz --ply m.npz` the map with its PLY (exit 0 each),
`calib convert c.ini c.ini` rewrote the calibration in place, and an --out naming a FIFO or a device node replaced
it with a plain file (as root, `--out /dev/null` would have replaced /dev/null)."""
from __future__ import annotations

import errno
import hashlib
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from drivers import fileio as driver_fileio
from estimation import fileio as estimation_fileio
from mocks.stereo_head import default_calibration_text
from runtime.sensorlog import SensorLogWriter
from tests.datasets.conftest import run_cli


def _digests(*paths: Path) -> dict[str, str]:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


def _refused(argv: list[str], *kept: Path, says: str) -> None:
    before = _digests(*kept)
    status, _, err = run_cli(*argv)
    assert status == 2 and err.count("\n") == 1 and says in err, (status, err)
    assert _digests(*kept) == before


@pytest.fixture(scope="module")
def sensor_log(tmp_path_factory) -> Path:
    """A small replayable log (a synthetic camera's observations): its one segment."""
    folder = tmp_path_factory.mktemp("log") / "robot1-log"
    rng = np.random.default_rng(0)
    with SensorLogWriter(folder, {"robot": "robot1", "seed": 0}) as writer:
        for k in range(20):
            t = 0.1 * k
            writer.write("odometry", {"t": t, "x": 0.05 * k, "y": 0.0, "theta": 0.0, "v": 0.5, "w": 0.0,
                                      "stalled": False, "sonar": np.full(8, np.nan), "sonar_poses": np.zeros((8, 3)),
                                      "raw": np.zeros(10, np.uint8)})
            if k % 2 == 0 and k:
                n = 4
                writer.write("observations", {"t": t, "seq": k, "points": rng.uniform(1, 5, (n, 3)),
                                              "covariances": np.tile(np.eye(3) * 1e-3, (n, 1, 1)),
                                              "descriptors": rng.normal(size=(n, 64)).astype(np.float32),
                                              "pixels": rng.uniform(0, 640, (n, 2))})
                writer.write("processed", {"t": t, "seq": k})
    (segment,) = sorted(folder.glob("*.mcap"))
    return segment


def test_replay_writes_no_map_over_its_log(sensor_log, tmp_path) -> None:
    status, _, err = run_cli("replay", str(sensor_log), "--out", str(tmp_path / "map.npz"))
    assert status == 0, err                              # the log replays: the refusals below are about --out
    _refused(["replay", str(sensor_log), "--out", str(sensor_log)], sensor_log, says="is the sensor log file")
    _refused(["replay", str(sensor_log.parent), "--out", str(sensor_log)], sensor_log,
             says="is inside the sensor log folder")
    _refused(["replay", str(sensor_log.parent), "--out", str(sensor_log.parent / "map.npz")], sensor_log,
             says="is inside the sensor log folder")
    assert sorted(p.name for p in sensor_log.parent.iterdir()) == [sensor_log.name]


def test_features_writes_no_csv_over_its_images(tmp_path) -> None:
    status, _, err = run_cli("camera", "grab", "--mock", "--out", str(tmp_path))
    assert status == 0, err
    left, right = tmp_path / "left.png", tmp_path / "right.png"
    for target, role in ((left, "left image"), (right, "right image")):
        _refused(["features", str(left), str(right), "--virtual-head", "--out", str(target)], left, right,
                 says=f"is the {role} file")


def test_slam_simulate_writes_its_map_and_ply_apart_and_over_no_input(tmp_path) -> None:
    route = tmp_path / "route.txt"
    route.write_text("3 5\n6 5\n")
    base = ["slam", "simulate", "--seconds", "1"]
    _refused([*base, "--out", str(tmp_path / "m.npz"), "--ply", str(tmp_path / "m.npz")], route,
             says="is the --out file")
    assert not (tmp_path / "m.npz").exists()
    _refused([*base, "--world-route", str(route), "--out", str(route)], route, says="is the --world-route file")
    _refused([*base, "--world-route", str(route), "--out", str(tmp_path / "m.npz"), "--ply", str(route)], route,
             says="is the --world-route file")


def test_calib_convert_rewrites_no_input_and_names_an_unknown_format(tmp_path) -> None:
    ini = tmp_path / "head.ini"
    ini.write_text(default_calibration_text())
    _refused(["calib", "convert", str(ini), str(ini)], ini, says="is the IN file")
    _refused(["calib", "convert", str(ini), str(tmp_path / "." / "head.ini")], ini, says="is the IN file")
    status, _, err = run_cli("calib", "convert", str(ini), str(tmp_path / "info"))
    assert status == 0, err
    kept = sorted((tmp_path / "info").iterdir())
    _refused(["calib", "convert", str(tmp_path / "info"), str(tmp_path / "info")], *kept, says="is the IN file")
    _refused(["calib", "convert", str(ini), str(tmp_path / "head.txt")], ini, says="unknown calibration format")
    assert not (tmp_path / "head.txt").exists()


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_an_output_where_a_fifo_or_device_is_is_refused_and_left_there(tmp_path, kind) -> None:
    node = tmp_path / "node"
    if kind == "fifo":
        os.mkfifo(node)
    else:
        if os.geteuid() != 0:
            pytest.skip("creating a device node needs root")
        os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 3))   # a second /dev/null
    mode = node.stat().st_mode
    status, _, err = run_cli("slam", "simulate", "--seconds", "1", "--out", str(node))
    assert status == 2 and err.count("\n") == 1 and "not a file" in err, err
    for fileio in (estimation_fileio, driver_fileio):   # the writer itself, whoever calls it
        with pytest.raises(OSError) as info:
            fileio.atomic_write_bytes(node, b"x")
        assert info.value.errno == errno.EINVAL
    assert node.stat().st_mode == mode and not [p for p in tmp_path.iterdir() if p != node]
