"""A map read back from a recording is the map that was logged: each snapshot carries a CRC-32 of its arrays, and a
snapshot whose bytes changed in the file (a flipped bit that still decodes: Rerun's messages have no checksum) is
left out, the one before it read, and said so."""
from __future__ import annotations

import json

import numpy as np

from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording
from tests.runtime.rerun_helpers import landmark_map


def _recording(path, snapshots):
    log = MissionLog(open_recording(str(path)), ["robot1"])
    for t, m in enumerate(snapshots):
        log.log_map("robot1", float(t), m)
        log.flush()     # one message per snapshot, in order
    log.close()


def _flip_in(path, values: np.ndarray, occurrence: int = -1) -> None:
    """Flip the low bit of the first byte of ``values`` (float64) where the file holds them: Rerun compresses its
    messages with LZ4, which keeps random bytes (uniform positions) as literals, so the message still decodes, with
    one number changed."""
    data = bytearray(path.read_bytes())
    needle = np.ascontiguousarray(values, float).tobytes()[:48]   # the first six numbers
    places, start = [], 0
    while (at := data.find(needle, start)) >= 0:
        places.append(at)
        start = at + 1
    assert places, "the array's bytes are not in the file as written"
    data[places[occurrence]] ^= 0x01
    path.write_bytes(bytes(data))


def test_an_untouched_recording_reads_every_map_as_logged(tmp_path):
    rng = np.random.default_rng(0)
    first, last = landmark_map("robot1", 30, rng), landmark_map("robot1", 40, rng)
    _recording(tmp_path / "r.rrd", [first, last])
    contents = read_recording(tmp_path / "r.rrd")
    assert contents.damaged is None
    np.testing.assert_array_equal(contents.maps["robot1"].positions, last.positions)
    np.testing.assert_array_equal(contents.maps["robot1"].covariances, last.covariances)


def test_a_snapshot_changed_in_the_file_is_left_out_and_the_one_before_read(tmp_path):
    rng = np.random.default_rng(1)
    first, last = landmark_map("robot1", 30, rng), landmark_map("robot1", 40, rng)
    path = tmp_path / "r.rrd"
    _recording(path, [first, last])
    _flip_in(path, last.positions)
    contents = read_recording(path)
    np.testing.assert_array_equal(contents.maps["robot1"].positions, first.positions)   # not a changed map
    assert "maps/robot1" in contents.damaged and "checksum" in contents.damaged


def test_a_map_whose_every_snapshot_changed_is_left_out_and_the_other_maps_read(tmp_path):
    rng = np.random.default_rng(2)
    changed, intact = landmark_map("robot1", 30, rng), landmark_map("robot2", 35, rng)
    path = tmp_path / "r.rrd"
    log = MissionLog(open_recording(str(path)), ["robot1", "robot2"])
    log.log_map("robot1", 0.0, changed)
    log.log_map("robot2", 0.0, intact)
    log.close()
    _flip_in(path, changed.positions)
    contents = read_recording(path)
    assert "robot1" not in contents.maps                  # no snapshot of it is the map that was logged
    np.testing.assert_array_equal(contents.maps["robot2"].positions, intact.positions)
    assert "maps/robot1: every snapshot (1) fails its checksum" in contents.damaged
    assert "left out" in contents.damaged and "\n" not in contents.damaged


def _log_undecodable_snapshot(log: MissionLog, key: str, t: float, like) -> None:
    """A snapshot of ``like`` whose descriptors are gone (what a flipped bit in an array's length did in a CI run:
    "cannot reshape array of size 0 into shape (8,1)"): every other field as MissionLog writes it."""
    import rerun as rr

    log.rec.set_time("sim_time", duration=t)
    log.rec.log(f"maps/{key}", rr.AnyValues(
        positions=like.positions.ravel(), covariances=like.covariances.ravel(), ids=like.ids, counts=like.counts,
        seen_by=like.seen_by.astype(np.uint8).ravel(), trajectory=np.asarray(like.trajectory, float).ravel(),
        descriptor_size=int(like.descriptor_size), size=len(like), t=t,
        meta=json.dumps({"robot": key, "frame": "start", "robots": [key], "metadata": {}})))


def test_a_snapshot_that_no_longer_decodes_is_left_out_and_the_one_before_read(tmp_path):
    rng = np.random.default_rng(3)
    first, last = landmark_map("robot1", 30, rng), landmark_map("robot1", 40, rng)
    path = tmp_path / "r.rrd"
    log = MissionLog(open_recording(str(path)), ["robot1"])
    log.log_map("robot1", 0.0, first)
    log.flush()
    _log_undecodable_snapshot(log, "robot1", 1.0, last)
    log.close()
    contents = read_recording(path)
    np.testing.assert_array_equal(contents.maps["robot1"].positions, first.positions)
    assert "maps/robot1: the last 1 snapshot(s) are damaged (does not decode into a map: " in contents.damaged


def test_a_map_that_never_decodes_is_left_out_and_the_other_maps_read(tmp_path):
    rng = np.random.default_rng(4)
    broken, intact = landmark_map("robot1", 30, rng), landmark_map("robot2", 35, rng)
    path = tmp_path / "r.rrd"
    log = MissionLog(open_recording(str(path)), ["robot1", "robot2"])
    _log_undecodable_snapshot(log, "robot1", 0.0, broken)
    log.log_map("robot2", 0.0, intact)
    log.close()
    contents = read_recording(path)   # it refused the whole file ("holds a malformed map"), losing robot2's map
    assert "robot1" not in contents.maps
    np.testing.assert_array_equal(contents.maps["robot2"].positions, intact.positions)
    assert "maps/robot1: every snapshot (1) is damaged (does not decode into a map: " in contents.damaged
    assert "left out" in contents.damaged and "\n" not in contents.damaged
