"""MCAP sensor logs: written with ROS 2 types, read back exactly, read by independent readers (mcap + its ROS 2
decoder, rosbags), readable after a SIGKILL at any moment, and a reader that refuses damage cleanly."""
from __future__ import annotations

import functools
import os
import signal
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime import ros2_messages as ros
from runtime.cli import main
from runtime.sensorlog import SensorLog, SensorLogError, SensorLogWriter

REPO = Path(__file__).resolve().parents[2]
GEOMETRY = {"fx": 520.0, "fy": 521.0, "cx": 319.5, "cy": 239.5, "baseline": 0.09,
            "head_pose": [0.12, 0.0, 0.5, 0.0, 0.0, 0.0], "left_camera_pose": None}
SONARS = 8


def _records(n_sips: int, rng: np.random.Generator, images: bool = True, start: float = 50.0):
    """(stream, record) pairs as the runtime hands them over, in time order: SIPs at 10 Hz, a frame every other."""
    out = []
    for k in range(n_sips):
        t = start + 0.1 * k + rng.uniform(0, 1e-3)  # arbitrary float seconds: replay needs them exactly
        sonar = rng.uniform(0.2, 5.0, SONARS)
        sonar[k % SONARS] = np.nan
        out.append(("odometry", {"t": t, "x": rng.normal(), "y": rng.normal(), "theta": rng.uniform(-np.pi, np.pi),
                                 "v": 0.3, "w": -0.1, "stalled": k % 7 == 0, "sonar": sonar,
                                 "sonar_poses": np.column_stack([np.zeros(SONARS), np.zeros(SONARS),
                                                                 np.linspace(-1.5, 1.5, SONARS)]),
                                 "raw": rng.integers(0, 256, 40, dtype=np.uint8)}))
        if k % 2:
            continue
        t_frame = t + 0.0371
        if images:
            left = rng.integers(0, 256, (48, 64), dtype=np.uint8)
            out.append(("frames", {"t": t_frame, "seq": k, "left": left, "right": np.roll(left, 3, axis=1)}))
        else:
            n = int(rng.integers(0, 6))
            a = rng.normal(size=(n, 3, 3))
            out.append(("observations", {"t": t_frame, "seq": k, "points": rng.normal(size=(n, 3)),
                                         "covariances": a @ np.swapaxes(a, 1, 2),
                                         "descriptors": rng.normal(size=(n, 64)).astype(np.float32),
                                         "pixels": rng.uniform(0, 640, (n, 2))}))
        out.append(("processed", {"t": t_frame, "seq": k}))
    return out


def _write(folder: Path, records, **options) -> SensorLogWriter:
    with SensorLogWriter(folder, {"robot": "robot1", "geometry": GEOMETRY, "seed": 7}, **options) as writer:
        for stream, record in records:
            writer.write(stream, record)
    return writer


@pytest.mark.parametrize("images", [True, False])
def test_every_stream_reads_back_exactly_across_segments(tmp_path, images):
    records = _records(60, np.random.default_rng(1), images)
    writer = _write(tmp_path / "robot1-log", records, segment_seconds=2.0)
    log = SensorLog(tmp_path / "robot1-log")
    assert log.closed and not log.warnings
    assert len(writer.segments) == len(log.files) >= 3  # 6 s of log in 2 s segments
    assert all(p.suffix == ".mcap" for p in log.files) and not list((tmp_path / "robot1-log").glob("*.part"))
    assert log.metadata["robot"] == "robot1" and log.metadata["seed"] == 7 and log.metadata["geometry"] == GEOMETRY
    for stream in ("odometry", "frames", "observations", "processed"):
        want = [r for s, r in records if s == stream]
        got = list(log.records(stream))
        assert log.count(stream) == len(got) == len(want), stream
        for g, w in zip(got, want, strict=True):
            assert g["t"] == w["t"]  # bit for bit
            for key in set(w) - {"sonar", "sonar_poses", "stalled", "raw"}:
                np.testing.assert_array_equal(np.asarray(g[key]), np.asarray(w[key]), err_msg=f"{stream}.{key}")
            if stream == "odometry":
                assert g["raw"] == w["raw"].tobytes() and g["stalled"] == int(w["stalled"])


def _decoded(path: Path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None  # a complete, indexed MCAP file
        return list(reader.iter_decoded_messages()), summary


def test_mcaps_own_reader_with_the_ros2_decoder_reads_the_expected_topics_types_and_counts(tmp_path):
    records = _records(30, np.random.default_rng(2))
    _write(tmp_path / "log", records, segment_seconds=100.0)
    (segment,) = SensorLog(tmp_path / "log").files
    messages, summary = _decoded(segment)
    by_topic: dict[str, list] = {}
    for schema, channel, _, decoded in messages:
        by_topic.setdefault(channel.topic, []).append((schema.name, decoded))
    sips, frames = 30, 15
    expected = {"/robot1/sip": ("p3at_msgs/msg/RawSip", sips), "/robot1/odom": ("nav_msgs/msg/Odometry", sips),
                "/tf": ("tf2_msgs/msg/TFMessage", sips),
                "/robot1/stereo/left/image_rect/compressed": ("sensor_msgs/msg/CompressedImage", frames),
                "/robot1/stereo/right/image_rect/compressed": ("sensor_msgs/msg/CompressedImage", frames),
                "/robot1/stereo/left/camera_info": ("sensor_msgs/msg/CameraInfo", frames),
                "/robot1/stereo/right/camera_info": ("sensor_msgs/msg/CameraInfo", frames),
                "/robot1/stereo/frame": ("p3at_msgs/msg/FrameStamp", frames),
                "/robot1/slam/processed": ("p3at_msgs/msg/FrameStamp", frames)}
    expected |= {f"/robot1/sonar/sonar_{i}": ("sensor_msgs/msg/Range", sips) for i in range(SONARS)}
    assert "/tf_static" in by_topic
    assert {k: (v[0][0], len(v)) for k, v in by_topic.items() if k != "/tf_static"} == expected
    odom = [r for s, r in records if s == "odometry"]
    first = by_topic["/robot1/odom"][0][1]
    assert (first.pose.pose.position.x, first.pose.pose.position.y) == (odom[0]["x"], odom[0]["y"])
    q = first.pose.pose.orientation
    assert np.isclose(2 * np.arctan2(q.z, q.w), odom[0]["theta"])
    assert first.header.frame_id == "robot1/odom" and first.child_frame_id == "robot1/base_link"
    right = by_topic["/robot1/stereo/right/camera_info"][0][1]
    assert right.p[3] == -GEOMETRY["fx"] * GEOMETRY["baseline"] and (right.width, right.height) == (64, 48)
    assert right.distortion_model == "plumb_bob" and list(right.k) == [520.0, 0, 319.5, 0, 521.0, 239.5, 0, 0, 1]
    ranges = [m for _, m in by_topic[f"/robot1/sonar/sonar_{0}"]]
    assert ranges[0].range == np.inf and ranges[1].range == np.float32(odom[1]["sonar"][0])
    image = by_topic["/robot1/stereo/left/image_rect/compressed"][0][1]
    import cv2

    left = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(left, next(r for s, r in records if s == "frames")["left"])  # lossless
    static = by_topic["/tf_static"][-1][1]
    children = {t.child_frame_id for t in static.transforms}
    assert {"robot1/stereo_left_optical", "robot1/stereo_right_optical", "robot1/sonar_0"} <= children
    assert summary.statistics.message_count == len(messages)


def test_rosbags_reads_the_segments_with_their_embedded_definitions(tmp_path):
    from rosbags.highlevel import AnyReader

    records = _records(40, np.random.default_rng(3), images=False)
    _write(tmp_path / "log", records, segment_seconds=1.5)
    files = SensorLog(tmp_path / "log").files
    assert len(files) > 1
    with AnyReader(files) as reader:  # no type store given: the types come from the files themselves
        counts: dict[str, int] = {}
        types = {c.topic: c.msgtype for c in reader.connections}
        observations = []
        for connection, _, raw in reader.messages():
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
            if connection.topic == "/robot1/stereo/observations":
                observations.append(reader.deserialize(raw, connection.msgtype))
    assert counts["/robot1/sip"] == counts["/robot1/odom"] == 40 and counts["/robot1/stereo/observations"] == 20
    assert types["/robot1/odom"] == "nav_msgs/msg/Odometry" and types["/tf_static"] == "tf2_msgs/msg/TFMessage"
    want = [r for s, r in records if s == "observations"]
    for got, w in zip(observations, want, strict=True):
        assert got.seq == w["seq"] and got.t == w["t"] and got.count == len(w["points"])
        np.testing.assert_array_equal(np.asarray(got.points).reshape(-1, 3), w["points"])


def test_standard_message_definitions_are_the_ros2_ones():
    """Each standard type's fields, as rosbags parses our definition, equal rosbags' own ROS 2 Jazzy store."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    jazzy = get_typestore(Stores.ROS2_JAZZY)
    for name in ros.TYPES:
        if name.startswith("p3at_msgs/"):
            continue
        text = ros.message_definition(name)
        parts = text.split(ros.SEPARATOR + "\n")
        types = get_types_from_msg(parts[0], ros.schema_name(name))
        for part in parts[1:]:
            header, body = part.split("\n", 1)
            types |= get_types_from_msg(body, ros.schema_name(header.removeprefix("MSG: ")))
        for type_name, fields in types.items():
            assert jazzy.fielddefs[type_name] == fields, type_name


def test_the_cdr_codec_matches_mcap_ros2s_decoder_for_every_type():
    from mcap_ros2._dynamic import generate_dynamic

    rng = np.random.default_rng(4)
    T = np.eye(4)
    T[:3, 3] = (0.1, -0.2, 0.5)
    samples = {
        "p3at_msgs/RawSip": (ros.encode_raw_sip(5, "o", 1.25, b"\x32\x00\xff", 1.0, 2.0, 3.0, 4.0, 5.0, True),
                             {"t": 1.25, "payload": b"\x32\x00\xff", "theta": 3.0, "stalled": True}),
        "p3at_msgs/FrameStamp": (ros.encode_frame_stamp(-3, "c", 2**40, 0.1), {"seq": 2**40, "t": 0.1}),
        "tf2_msgs/TFMessage": (ros.encode_transforms(1, [("a", "b", T)]), {}),
        "sensor_msgs/Image": (ros.encode_image(1, "c", rng.integers(0, 256, (3, 5, 3), dtype=np.uint8)),
                              {"encoding": "bgr8", "step": 15, "width": 5}),
    }
    for name, (data, fields) in samples.items():
        decoded = generate_dynamic(ros.schema_name(name), ros.message_definition(name))[ros.schema_name(name)](data)
        for key, value in fields.items():
            assert getattr(decoded, key) == value, (name, key)
    assert decoded.header.stamp.sec == 0
    stamp = generate_dynamic("p3at_msgs/msg/FrameStamp", ros.message_definition("p3at_msgs/FrameStamp"))[
        "p3at_msgs/msg/FrameStamp"](samples["p3at_msgs/FrameStamp"][0]).header.stamp
    assert (stamp.sec, stamp.nanosec) == (-1, 999_999_997)  # negative stamps floor, as builtin_interfaces does


_WRITER_SCRIPT = """
import sys, numpy as np
sys.path.insert(0, {repo!r})
from runtime.sensorlog import SensorLogWriter
rng = np.random.default_rng(0)
with SensorLogWriter({folder!r}, {{"robot": "robot1"}}, segment_seconds=0.5, flush_interval=0.1) as w:
    k = 0
    while True:
        t = 0.05 * k
        w.write("odometry", {{"t": t, "x": 0.01 * k, "y": 0.0, "theta": 0.0, "sonar": rng.random(4),
                              "sonar_poses": np.zeros((4, 3)), "raw": np.zeros(30, np.uint8)}})
        w.write("observations", {{"t": t, "seq": k, "points": rng.normal(size=(50, 3)),
                                  "covariances": np.tile(np.eye(3), (50, 1, 1)),
                                  "descriptors": rng.normal(size=(50, 64)).astype(np.float32),
                                  "pixels": rng.random((50, 2))}})
        k += 1
        if k % 20 == 0:
            w.flush()
            print(k, flush=True)
"""


@pytest.mark.parametrize("lines_before_kill", [1, 3, 7, 12])
def test_a_log_killed_at_any_moment_stays_readable(tmp_path, lines_before_kill):
    """SIGKILL a writing process after a varying amount of progress (counted in flushed batches, not seconds):
    every file it leaves opens, the closed segments are complete MCAP files, the .part is read up to its cut."""
    folder = tmp_path / "log"
    process = subprocess.Popen([sys.executable, "-c", _WRITER_SCRIPT.format(repo=str(REPO), folder=str(folder))],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(lines_before_kill):
            assert process.stdout.readline(), process.stderr.read()
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    log = SensorLog(folder)
    flushed = 20 * lines_before_kill  # the writer printed after flushing this many records of each stream
    assert log.count("odometry") >= flushed and log.count("observations") >= flushed
    seqs = [r["seq"] for r in log.records("observations")]
    assert seqs == list(range(len(seqs)))  # nothing lost before the cut, nothing out of order
    for f in log.files:
        if f.suffix == ".mcap":
            _decoded(f)  # each closed segment: summary, statistics, decodable by mcap's own reader
    assert all(f.suffix == ".mcap" for f in log.files[:-1])  # only the last can be a .part


def test_the_writer_bounds_its_memory_and_counts_what_it_could_not_take(tmp_path):
    writer = SensorLogWriter(tmp_path / "log", {"robot": "r"}, flush_interval=1e9, max_queued_bytes=200_000)
    image = np.random.default_rng(0).integers(0, 256, (240, 320), dtype=np.uint8)  # 77 kB a side: 154 kB a frame
    for i in range(50):  # faster than any PNG encoder: most frames are over the 200 kB budget
        writer.write("frames", {"t": 0.1 * i, "seq": i, "left": image, "right": image})
    writer.close()
    log = SensorLog(tmp_path / "log")
    assert writer.dropped > 0 and log.count("frames") + writer.dropped == 50


def test_bad_logs_give_one_line_and_exit_2(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SensorLogError, match="no sensor log here"):
        SensorLog(empty)
    old = tmp_path / "old"
    old.mkdir()
    (old / "index.json").write_text("{}")
    with pytest.raises(SensorLogError, match="format 1"):
        SensorLog(old)
    garbage = tmp_path / "garbage"
    garbage.mkdir()
    (garbage / "garbage_0.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x07" * 100)
    for path in (empty, old, garbage, tmp_path / "missing"):
        assert main(["replay", str(path)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and str(path) in err and "Traceback" not in err


@functools.cache
def _small_log() -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "log"
        _write(folder, _records(8, np.random.default_rng(5), images=True), segment_seconds=100.0)
        (segment,) = folder.iterdir()
        return segment.read_bytes()


_damage = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0, 1), st.just(b"")),
    st.tuples(st.just("flip"), st.floats(0, 1), st.binary(min_size=1, max_size=8)),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=64)),
    st.tuples(st.just("huge"), st.floats(0, 1), st.sampled_from([b"\xff" * 8, b"\x00\x00\x00\x40" * 2])),
)


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(damages=st.lists(_damage, min_size=1, max_size=3), part=st.booleans())
def test_fuzzed_logs_give_a_clean_error_or_valid_records_in_bounded_memory(tmp_path, damages, part):
    small_log = _small_log()
    data = bytearray(small_log)
    for kind, where, payload in damages:
        at = int(where * len(data))
        if kind == "truncate":
            del data[at:]
        elif kind == "insert":
            data[at:at] = payload
        else:
            data[at:at + len(payload)] = payload
    folder = tmp_path / f"fuzz{os.getpid()}_{time.monotonic_ns()}"
    folder.mkdir()
    (folder / ("robot1_0.mcap.part" if part else "robot1_0.mcap")).write_bytes(bytes(data))
    tracemalloc.start()
    try:
        log = SensorLog(folder)
        for stream in ("odometry", "frames", "processed"):
            for record in log.records(stream):
                assert np.isfinite(record["t"])
    except SensorLogError as e:
        assert str(folder) in str(e)
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert peak < 20 * len(small_log) + (8 << 20)  # bounded by the file, whatever its fields claim


_VALID_MESSAGES = {
    "/robot1/sip": ("p3at_msgs/RawSip", ros.encode_raw_sip(1, "o", 0.5, b"\x32" * 30, 1.0, 2.0, 0.3, 0.1, 0.0, False)),
    "/robot1/slam/processed": ("p3at_msgs/FrameStamp", ros.encode_frame_stamp(1, "b", 4, 0.5)),
    "/robot1/stereo/observations": ("p3at_msgs/StereoObservations", ros.encode_observations(
        1, "b", 4, 0.5, np.ones((3, 3)), np.tile(np.eye(3), (3, 1, 1)), np.ones((3, 4)), np.ones((3, 2)))),
}


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(topic=st.sampled_from(sorted(_VALID_MESSAGES)), cut=st.integers(0, 400), at=st.integers(0, 400),
       patch=st.binary(min_size=1, max_size=8))
def test_damaged_messages_inside_a_sound_file_give_a_clean_error_or_valid_records(tmp_path, topic, cut, at, patch):
    """The container is intact (CRCs right); the message bytes lie: counts past the end, NaNs, bad text."""
    from mcap.writer import Writer

    type_name, data = _VALID_MESSAGES[topic]
    data = bytearray(data[:max(4, cut)] if cut < len(data) else data)
    data[at:at + len(patch)] = patch
    folder = tmp_path / f"m{time.monotonic_ns()}"
    folder.mkdir()
    with open(folder / "robot1_0.mcap", "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2")
        schema = writer.register_schema(ros.schema_name(type_name), "ros2msg",
                                        ros.message_definition(type_name).encode())
        channel = writer.register_channel(topic, "cdr", schema)
        writer.add_message(channel, log_time=1, publish_time=1, data=bytes(data))
        writer.finish()
    stream = {"/robot1/sip": "odometry", "/robot1/slam/processed": "processed",
              "/robot1/stereo/observations": "observations"}[topic]
    try:
        for record in SensorLog(folder).records(stream):
            assert np.isfinite(record["t"])
            if stream == "observations":
                assert np.all(np.isfinite(record["points"])) and record["covariances"].shape[1:] == (3, 3)
    except SensorLogError as e:
        assert "robot1_0.mcap" in str(e) and topic in str(e)


def test_the_cdr_codec_writes_the_bytes_mcap_ros2s_encoder_writes():
    from mcap_ros2._dynamic import serialize_dynamic

    rng = np.random.default_rng(6)
    header = {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "r/base_link"}
    n = 7
    p, c, px = rng.normal(size=(n, 3)), rng.normal(size=(n, 3, 3)), rng.normal(size=(n, 2))
    d = rng.normal(size=(n, 16)).astype(np.float32)
    cases = [
        ("p3at_msgs/StereoObservations", ros.encode_observations(1_000_000_002, "r/base_link", 9, 0.25, p, c, d, px),
         {"header": header, "seq": 9, "t": 0.25, "count": n, "descriptor_size": 16, "points": p.ravel().tolist(),
          "covariances": c.ravel().tolist(), "descriptors": d.ravel().tolist(), "pixels": px.ravel().tolist()}),
        ("sensor_msgs/CompressedImage", ros.encode_compressed_image(1_000_000_002, "r/base_link", "png", b"\x89PNG"),
         {"header": header, "format": "png", "data": b"\x89PNG"}),
        ("p3at_msgs/RawSip", ros.encode_raw_sip(1_000_000_002, "r/base_link", 0.5, b"\x32\x33", 1.0, -2.0, 0.1,
                                                 0.2, 0.3, True),
         {"header": header, "t": 0.5, "payload": b"\x32\x33", "x": 1.0, "y": -2.0, "theta": 0.1, "v": 0.2,
          "w": 0.3, "stalled": True}),
        ("sensor_msgs/Range", ros.encode_range(1_000_000_002, "r/base_link", 0.26, 0.1, 5.0, 1.5),
         {"header": header, "radiation_type": 0, "field_of_view": 0.26, "min_range": 0.1, "max_range": 5.0,
          "range": 1.5, "variance": 0.0}),
    ]
    for name, ours, message in cases:
        encoder = serialize_dynamic(ros.schema_name(name), ros.message_definition(name))[ros.schema_name(name)]
        assert ours == encoder(message), name


def test_replay_says_when_frames_the_live_run_processed_are_missing(tmp_path, capsys):
    from runtime.replay import replay_log

    records = _records(30, np.random.default_rng(7), images=False)
    lost = next(r["seq"] for s, r in records if s == "observations" and r["seq"] > 4)
    kept = [(s, r) for s, r in records if not (s == "observations" and r["seq"] == lost)]  # the writer dropped it
    _write(tmp_path / "log", kept)
    whole = tmp_path / "whole"
    _write(whole, records)
    assert replay_log(tmp_path / "log").missing_frames == 1 and replay_log(whole).missing_frames == 0
    assert main(["replay", str(tmp_path / "log"), "--particles", "3"]) == 0
    assert "1 frames the live run processed are not in the log" in capsys.readouterr().err
    assert main(["replay", str(whole), "--particles", "3", "--version", "1"]) == 0  # the deprecated spelling
    err = capsys.readouterr().err
    assert "--version is deprecated" in err and "use --fastslam" in err
