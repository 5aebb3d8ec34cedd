"""``p3at replay`` on what a lab hands it besides a whole log: a segment copied in part, an empty file, another
tool's ROS 2 bag. One line naming the file and what to do, exit 2; never "0 frames, 0 landmarks" with exit 0."""
from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from runtime.cli import main

from .test_sensorlog_mcap import _records, _write


@functools.cache
def _segment() -> bytes:
    """One whole segment of a small synthetic-camera log (observations, no images)."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "log"
        _write(folder, _records(30, np.random.default_rng(3), images=False), segment_seconds=100.0,
               chunk_size=2048)
        (segment,) = folder.iterdir()
        return segment.read_bytes()


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_a_whole_segment_replays(tmp_path, capsys):
    """The premise: the segment the cuts below start from is a good log."""
    path = tmp_path / "robot1-log_0.mcap"
    path.write_bytes(_segment())
    assert main(["replay", str(path), "--particles", "3", "--json"]) == 0
    assert '"frames": 15' in capsys.readouterr().out


@settings(max_examples=25, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(0.0, 0.999))
@example(fraction=0.0).via("an empty file")
@example(fraction=0.5).via("cut mid-chunk")
def test_a_segment_cut_short_is_refused_in_one_line_that_names_the_way_out(tmp_path, capsys, fraction):
    """It said 'not a readable MCAP file (EndOfFile: )'."""
    data = _segment()
    path = tmp_path / "robot1-log_0.mcap"
    kept = int(fraction * len(data))
    path.write_bytes(data[:kept])
    assert main(["replay", str(path), "--particles", "3"]) == 2
    line = _err_line(capsys)
    assert line.startswith(f"p3at replay: {path}: ")
    assert ("an empty file" in line) if kept == 0 else ("cut short or damaged" in line
                                                         and "--allow-truncated" in line), line


@settings(max_examples=25, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(0.0, 0.999))
@example(fraction=0.02).via("cut before the first chunk")
def test_allow_truncated_replays_the_complete_chunks_or_says_there_are_none(tmp_path, capsys, fraction):
    data = _segment()
    path = tmp_path / "robot1-log_0.mcap"
    path.write_bytes(data[: int(fraction * len(data))])
    code = main(["replay", str(path), "--particles", "3", "--allow-truncated"])
    line = _err_line(capsys)
    if code == 0:
        assert line == f"p3at replay: warning: {path}: cut short; read up to its last complete chunk"
    else:
        assert code == 2 and line.startswith(f"p3at replay: {path}: "), line
        assert "holds no complete message" in line or "an empty file" in line, line


def test_another_tools_ros2_bag_is_not_replayed_as_an_empty_run(tmp_path, capsys):
    """It replayed as 'robot, 0 frames ... map: 0 landmarks', exit 0."""
    from mcap_ros2.writer import Writer

    bag = tmp_path / "lab_run.mcap"
    with bag.open("wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef("std_msgs/msg/String", "string data")
        for k in range(5):
            writer.write_message(topic="/chatter", schema=schema, message={"data": f"{k}"}, log_time=k, publish_time=k)
        writer.finish()
    assert main(["replay", str(bag)]) == 2
    line = _err_line(capsys)
    assert line == (f"p3at replay: {bag}: not a p3at sensor log (no 'p3at-sensor-log' settings record; its topics: "
                    "/chatter): replay reads the logs that p3at run/demo --log-sensors write")


def test_a_crash_part_cut_before_its_first_chunk_holds_nothing_to_replay(tmp_path, capsys):
    folder = tmp_path / "robot1-log"
    folder.mkdir()
    (folder / "robot1-log_0.mcap.part").write_bytes(_segment()[:40])
    assert main(["replay", str(folder)]) == 2
    assert _err_line(capsys) == (f"p3at replay: {folder}: holds no complete message (cut before its first chunk "
                                 "was written?)")
