"""A sensor log that lost records says so (session 47, F).

The sensor log's writer never blocks a driver: when the disk does not keep up (its queue full, or more than
`max_queued_bytes` waiting) it drops the record and counts it in `SensorLogWriter.dropped`. Nothing read that
count: the mission ended as if the log were whole, and a replay of it would not rebuild the live map. The summary
now carries each robot's `sensor_log_dropped`, the command says it on stderr (also with --quiet), and the
recording's events hold it. Here the writer has no room at all (a disk that takes nothing), so every record drops.
"""
from __future__ import annotations

import json

from runtime.cli import main
from runtime.sensorlog import SensorLogWriter


class _NoRoom(SensorLogWriter):
    def __init__(self, folder, metadata=None, **options):
        super().__init__(folder, metadata, **{**options, "max_queued_bytes": 0})


def test_a_sensor_log_that_dropped_records_is_said_in_the_summary_and_on_stderr(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("runtime.sensorlog.SensorLogWriter", _NoRoom)
    status = main(["run", "--camera", "synthetic", "--particles", "10", "--camera-rate", "5", "--seconds", "3",
                   "--rerun", "none", "--log-sensors", "--quiet", "--json", "--out", str(tmp_path / "run")])
    captured = capsys.readouterr()
    assert status == 0  # the robot mapped; its log is what is incomplete
    dropped = json.loads(captured.out)["robots"]["robot1"]["sensor_log_dropped"]
    assert dropped > 0
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("p3at run: warning: robot1's sensor log dropped"), captured.err
    assert f"dropped {dropped} records" in lines[0]


def test_a_whole_log_says_nothing(tmp_path, capsys):
    status = main(["run", "--camera", "synthetic", "--particles", "10", "--camera-rate", "5", "--seconds", "3",
                   "--rerun", "none", "--log-sensors", "--quiet", "--json", "--out", str(tmp_path / "run")])
    captured = capsys.readouterr()
    assert status == 0 and captured.err == ""
    assert json.loads(captured.out)["robots"]["robot1"]["sensor_log_dropped"] == 0
