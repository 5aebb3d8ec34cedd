"""Which clock a sensor log's stamps are on (session 26, C). On the wall clock the runtime's clock is the monotonic
one (seconds since boot): its header stamps and MCAP log times showed early January 1970 in Foxglove and rosbags,
and two machines' logs did not line up. Wall-clock logs now stamp on the epoch (ROS's convention), the runtime's
clock plus an offset read once and recorded in the settings; simulated-time logs stay sim time from 0; replay reads
the runtime's clock from the custom fields either way, so its map does not move."""
from __future__ import annotations

import datetime as dt
import time
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from runtime import ros2_messages as ros
from runtime.replay import replay_log
from runtime.sensorlog import EPOCH_OFFSET_KEY, SensorLog, SensorLogWriter, epoch_offset_ns

SETTINGS = {"robot": "robot1", "seed": 3, "fastslam": {"n_particles": 8}}
BOOT = 20_304.776220782   # s: where a monotonic clock is some hours after boot


def _write(folder: Path, epoch_offset: int | None, start: float = BOOT) -> list[tuple[str, dict]]:
    """A synthetic camera's log (SIPs at 10 Hz, observations at 5 Hz, all processed) from ``start`` s on."""
    rng = np.random.default_rng(0)
    landmarks = rng.uniform([1.0, -2.0, 0.2], [6.0, 2.0, 1.5], (25, 3))
    descriptors = rng.normal(size=(25, 64)).astype(np.float32)
    records = []
    for k in range(40):
        t = start + 0.1 * k + 1e-4 * (k % 3)
        x = 0.03 * k
        records.append(("odometry", {"t": t, "x": x, "y": 0.0, "theta": 0.0, "v": 0.3, "w": 0.0, "stalled": False,
                                     "sonar": np.full(8, 2.0), "sonar_poses": np.zeros((8, 3)),
                                     "raw": np.zeros(10, np.uint8)}))
        if k % 2:
            seen = np.flatnonzero(np.abs(landmarks[:, 0] - x - 3.0) < 2.5)
            points = landmarks[seen] - [x, 0.0, 0.0] + rng.normal(0, 0.01, (len(seen), 3))
            records.append(("observations", {"t": t + 0.02, "seq": k, "points": points,
                                             "covariances": np.tile(np.eye(3) * 1e-4, (len(seen), 1, 1)),
                                             "descriptors": descriptors[seen], "pixels": np.zeros((len(seen), 2))}))
            records.append(("processed", {"t": t + 0.02, "seq": k}))
    with SensorLogWriter(folder, SETTINGS, epoch_offset=epoch_offset, segment_seconds=1.5) as writer:
        for stream, record in records:
            writer.write(stream, record)
    return records


def test_the_offset_pairs_the_runtime_clock_with_the_epoch() -> None:
    offset = epoch_offset_ns(lambda: 100.0)   # a clock reading 100 s now
    assert abs(offset + 100 * 10**9 - time.time_ns()) < 60 * 10**9
    assert isinstance(offset, int)


def test_a_wall_clock_log_is_stamped_on_the_epoch_for_rosbags_and_mcap_and_records_the_offset(tmp_path) -> None:
    from rosbags.highlevel import AnyReader

    offset = epoch_offset_ns(time.monotonic)
    records = _write(tmp_path / "log", offset, start=time.monotonic())
    log = SensorLog(tmp_path / "log")
    assert len(log.files) > 1 and log.metadata[EPOCH_OFFSET_KEY] == offset == log.epoch_offset
    year = dt.datetime.now(dt.UTC).year
    with AnyReader(log.files) as reader:   # what a user's tool shows: today's date, not 1970
        assert dt.datetime.fromtimestamp(reader.start_time / 1e9, dt.UTC).year == year
        stamps = {}
        for connection, log_time, raw in reader.messages():
            if connection.topic == "/robot1/odom":
                header = reader.deserialize(raw, connection.msgtype).header.stamp
                stamps[log_time] = header.sec * 10**9 + header.nanosec
    sips = [r["t"] for s, r in records if s == "odometry"]
    # header stamp = log time = the runtime's clock (ns) + the offset, exactly
    assert sorted(stamps.items()) == [(ros.stamp_ns(t) + offset,) * 2 for t in sips]
    with open(log.files[0], "rb") as f:   # mcap + its ROS 2 decoder: the custom fields keep the runtime's clock
        for _, _, message, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/robot1/sip"]):
            assert decoded.t == sips[0] and message.log_time - offset == ros.stamp_ns(decoded.t)
            assert decoded.header.stamp.sec == (ros.stamp_ns(sips[0]) + offset) // 10**9
            break
    assert [r["t"] for r in log.records("odometry")] == sips            # bit for bit, as replay needs them
    first, last = log.time_span()
    assert abs(first - sips[0]) < 1e-6 and last >= sips[-1] - 1e-6     # on the runtime's clock again


def test_a_simulated_time_log_stays_on_sim_time_and_records_no_offset(tmp_path) -> None:
    records = _write(tmp_path / "log", None, start=0.0)
    log = SensorLog(tmp_path / "log")
    assert EPOCH_OFFSET_KEY not in log.metadata and log.epoch_offset == 0
    times = [m.log_time for m in log.messages({"/robot1/sip"})]
    assert times == [ros.stamp_ns(r["t"]) for s, r in records if s == "odometry"]


def test_replay_builds_the_same_map_from_a_log_with_or_without_the_offset(tmp_path) -> None:
    """A log without the offset is what wall-clock runs wrote before (stamps = the monotonic clock), byte for byte
    what a simulated-time run writes: it replays as before, and the same records stamped on the epoch replay to the
    very same map."""
    _write(tmp_path / "old", None)
    _write(tmp_path / "new", 1_796_407_942_566_434_741)
    old, new = replay_log(tmp_path / "old"), replay_log(tmp_path / "new")
    assert old.frames == new.frames >= 19 and len(old.landmark_map) > 5
    np.testing.assert_array_equal(old.final_pose, new.final_pose)
    assert old.log_span == new.log_span
    a, b = old.landmark_map, new.landmark_map
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.covariances, b.covariances)


def test_a_wall_clock_mission_stamps_its_log_on_the_epoch_and_replays_to_its_map(tmp_path) -> None:
    from runtime.mission import Mission, MissionConfig

    config = MissionConfig(robots=1, seconds=3.0, seed=1, camera="synthetic", camera_rate=5.0, particles=10,
                           fusion_interval=0.0, map_save_interval=0.0, out=tmp_path, rerun="none", realtime=True,
                           log_sensors=True)
    result = Mission(config).run()
    assert result.summary["clock"] == "wall" and not result.failures
    log = SensorLog(tmp_path / "robot1-log")
    assert abs(log.t_first - time.time_ns()) < 3600 * 10**9   # within the hour, on the epoch
    first, _ = log.time_span()
    assert abs(first - time.monotonic()) < 3600                # the runtime's clock: the monotonic one
    replayed = replay_log(log)
    live = np.load(tmp_path / "robot1.npz")
    assert replayed.frames > 0
    np.testing.assert_array_equal(replayed.landmark_map.positions, live["positions"])
