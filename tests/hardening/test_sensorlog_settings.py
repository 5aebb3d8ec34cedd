"""A sensor log's settings record, however hostile, gives a replay or one line and exit 2 (session 25, C). The
record is JSON the reader parsed but did not check: `replay` of a log claiming 10^9 particles, 10^8-long descriptors,
blocks of 10^9 landmarks ended in MemoryError (exit 70), a 'geometry' or 'harris' that is no object or a threshold
that is null in AttributeError/TypeError (exit 70), max_range 1e308 in OverflowError and RuntimeWarnings (exit 70,
5 lines), a seed of -1 or "abc" or a true start pose "abc" in exit 1, settings nested 10^5 deep in RecursionError
(exit 70); NaN gates replayed to a map (exit 0). Session 26 (C): a whole number beyond a float's range (JSON's integers
are unbounded: a seed of 10^400) ended in OverflowError, exit 70; a FastSLAM sensor offset of [] in "not enough
values to unpack", exit 1."""
from __future__ import annotations

import dataclasses
import functools
import io
import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from estimation.fastslam import FastSLAMConfig
from estimation.frontend import HarrisConfig, StereoGeometry
from runtime.sensorlog import METADATA_NAME, SensorLog, SensorLogError, SensorLogWriter
from tests.datasets.conftest import run_cli

BASE = {"robot": "robot1", "camera": "synthetic", "rectified": True, "geometry": StereoGeometry().to_dict(),
        "true_start_pose": [3.0, 5.0, 0.0], "seed": 0, "fastslam": {**FastSLAMConfig().to_dict(), "n_particles": 5},
        "harris": dataclasses.asdict(HarrisConfig()), "t0": 0.0}


@functools.cache
def _base_segment() -> bytes:
    """One segment of a small log written with BASE: a synthetic camera's observations."""
    with tempfile.TemporaryDirectory() as work:
        folder = Path(work) / "log"
        _record(folder, BASE)
        (segment,) = folder.glob("*.mcap")
        return segment.read_bytes()


def _write(folder: Path, metadata: dict, text: str | None = None) -> None:
    """The base segment with its settings record replaced by ``metadata`` (as JSON) or ``text`` (as it is): the
    writer itself reads some settings (the geometry), so a hostile record is made by copying."""
    folder.mkdir(parents=True)
    reader = make_reader(io.BytesIO(_base_segment()))
    with open(folder / "log_0.mcap", "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start("ros2", "p3at")
        writer.add_metadata(METADATA_NAME, {"settings": json.dumps(metadata) if text is None else text})
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages():
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas[schema.id], channel.metadata)
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,
                               message.sequence)
        writer.finish()


def _record(folder, metadata: dict) -> None:
    rng = np.random.default_rng(0)
    with SensorLogWriter(folder, metadata) as writer:
        for k in range(12):
            t = 0.1 * k
            writer.write("odometry", {"t": t, "x": 0.05 * k, "y": 0.0, "theta": 0.0, "v": 0.5, "w": 0.0,
                                      "stalled": False, "sonar": np.full(8, np.nan), "sonar_poses": np.zeros((8, 3)),
                                      "raw": np.zeros(10, np.uint8)})
            if k % 3 == 1:
                writer.write("observations", {"t": t, "seq": k, "points": rng.uniform(1, 5, (3, 3)),
                                              "covariances": np.tile(np.eye(3) * 1e-3, (3, 1, 1)),
                                              "descriptors": rng.normal(size=(3, 64)).astype(np.float32),
                                              "pixels": rng.uniform(0, 640, (3, 2))})
                writer.write("processed", {"t": t, "seq": k})


def _replayed(folder) -> tuple[int, str]:
    status, _, err = run_cli("replay", str(folder))
    assert "Traceback" not in err and "internal error" not in err, err
    assert status in (0, 2), (status, err)
    assert status == 0 or err.count("\n") == 1, err
    return status, err


def test_the_base_settings_replay(tmp_path) -> None:
    _write(tmp_path / "log", BASE)
    assert _replayed(tmp_path / "log")[0] == 0


@pytest.mark.parametrize(("change", "says"), [
    ({"fastslam": {**BASE["fastslam"], "n_particles": 10**9}}, "fastslam.n_particles must be"),
    ({"fastslam": {**BASE["fastslam"], "descriptor_size": 10**8}}, "fastslam.descriptor_size must be"),
    ({"fastslam": {**BASE["fastslam"], "block_size": 10**9 - 1}}, "fastslam.block_size must be"),
    ({"fastslam": {**BASE["fastslam"], "descriptor_slots": 10**8}}, "fastslam.descriptor_slots must be"),
    ({"fastslam": {**BASE["fastslam"], "descriptor_threshold": None}}, "fastslam.descriptor_threshold is null"),
    ({"fastslam": {**BASE["fastslam"], "max_range": 1e308}}, "fastslam.max_range is 1e+308"),
    ({"fastslam": {**BASE["fastslam"], "mahalanobis_gate": math.nan}}, "fastslam.mahalanobis_gate is nan"),
    ({"geometry": "x"}, "geometry is not an object"),
    ({"harris": [1]}, "harris is not an object"),
    ({"harris": {**BASE["harris"], "max_corners": 10**9}}, "harris.max_corners must be"),
    ({"seed": -1}, "seed must be a whole number >= 0"),
    ({"seed": "abc"}, "seed must be a whole number >= 0"),
    ({"true_start_pose": "abc"}, "true_start_pose must be three numbers"),
    ({"true_start_pose": [1.0, math.inf, 0.0]}, "true_start_pose[1] is inf"),
    ({"seed": 10**400}, "seed is a 401-digit number, beyond any float"),
    ({"true_start_pose": [10**309, 0, 0]}, "true_start_pose[0] is a 310-digit number"),
    ({"fastslam": {**BASE["fastslam"], "max_range": -(10**400)}}, "fastslam.max_range is a 401-digit number"),
    ({"fastslam": {**BASE["fastslam"], "sensor_offset": []}}, "fastslam.sensor_offset is [], not a list of 3 numbers"),
    ({"geometry": {**BASE["geometry"], "head_pose": [0.1, 0.2]}}, "geometry.head_pose is [0.1, 0.2], not a list of 6"),
    ({"epoch_offset_ns": "abc"}, "epoch_offset_ns must be a whole number"),
    ({"epoch_offset_ns": 1.5e18}, "epoch_offset_ns must be a whole number"),
    ({"epoch_offset_ns": 10**20}, "epoch_offset_ns must be a whole number"),
], ids=lambda v: str(v)[:40] if isinstance(v, str) else None)
def test_settings_a_replay_cannot_use_are_one_line(tmp_path, change, says) -> None:
    _write(tmp_path / "log", {**BASE, **change})
    status, err = _replayed(tmp_path / "log")
    assert status == 2 and "holds bad settings" in err and says in err, err


def test_settings_nested_too_deeply_are_one_line(tmp_path) -> None:
    _write(tmp_path / "log", BASE, text="[" * 100_000 + "]" * 100_000)
    with pytest.raises(SensorLogError, match="nested too deeply"):
        SensorLog(tmp_path / "log")
    status, err = _replayed(tmp_path / "log")
    assert status == 2 and "nested too deeply" in err


JSON_LEAF = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(), st.text(max_size=5))
JSON = st.recursive(JSON_LEAF, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner,
                                                                                            max_size=3), max_leaves=8)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(section=st.sampled_from(["fastslam", "geometry", "harris", None]), data=st.data())
def test_any_one_setting_changed_replays_or_is_one_line(tmp_path_factory, section, data) -> None:
    settings_ = json.loads(json.dumps(BASE))
    if section is None:
        key = data.draw(st.sampled_from(["seed", "true_start_pose", "t0", "robot", "camera", "epoch_offset_ns"]))
        settings_[key] = data.draw(JSON)
    else:
        key = data.draw(st.sampled_from(sorted(settings_[section])))
        settings_[section][key] = data.draw(JSON)
    folder = tmp_path_factory.mktemp("log") / "log"
    _write(folder, settings_)
    _replayed(folder)
