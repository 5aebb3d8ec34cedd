"""A fleet's processes write ONE recording: each opens its stream with the same recording id, then either streams to
one gRPC endpoint (a viewer, or `rerun --save`) or saves its own file; `p3at review` reads the files as one."""
from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from runtime.cli import main
from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording
from runtime.rerun_style import mission_blueprint

ROOT = Path(__file__).resolve().parents[2]
RECORDING_ID = "fleet-test-recording"


def _with_default_sigint() -> None:
    """preexec_fn: the child gets SIGINT as a terminal's Ctrl-C would, whatever this test process inherited
    (an ignored or blocked SIGINT is inherited across exec, and then Ctrl-C could not stop the child)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)

# what each robot's process runs: its own stream, the shared recording id, no blueprint (the fusion node sends it)
ROBOT_PROCESS = """
import sys, numpy as np
from runtime.rerun_log import MissionLog
from runtime.rerun_sink import open_recording
robot, sink, recording_id = sys.argv[1:4]
log = MissionLog(open_recording(sink, recording_id=recording_id), [robot], blueprint=False)
for frame in range(20):
    pose = np.array([0.1 * frame, 0.0, 0.0])
    log.log_pose(robot, 0.1 * frame, frame, pose, pose, odometry=pose)
    log.log_scalars(robot, 0.1 * frame, {"ess": 50.0, "landmarks/all": frame}, frame)
log.close()
"""


def _robot_processes(sink_of) -> None:
    children = [subprocess.Popen([sys.executable, "-c", ROBOT_PROCESS, robot, sink_of(robot), RECORDING_ID],
                                 cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
                for robot in ("robot1", "robot2")]
    for child in children:
        _, err = child.communicate(timeout=120)
        assert child.returncode == 0, err.decode(errors="replace")[-2000:]


def _log_fusion(sink: str) -> None:
    log = MissionLog(open_recording(sink, recording_id=RECORDING_ID,
                                    blueprint=mission_blueprint(["robot1", "robot2"])), [], blueprint=False)
    log.log_alignment(1.5, "robot1", "robot2", {"reference": "robot1", "other": "robot2", "aligned": True,
                                                "tx": 5.0, "ty": 0.0, "theta": np.pi, "supports": 20, "common": 9})
    log.close()


def _recording_ids(path: Path) -> set[str]:
    import rerun.chunk as rrchunk

    with warnings.catch_warnings():  # a server's saved stream has no footer: read by scanning
        warnings.simplefilter("ignore")
        return {store.recording_id for store in rrchunk.RrdReader(path).recordings()}


def test_processes_saving_their_own_file_make_one_recording_that_review_reads_as_one(tmp_path, capsys):
    _robot_processes(lambda robot: str(tmp_path / f"{robot}.rrd"))
    _log_fusion(str(tmp_path / "fusion.rrd"))
    files = [tmp_path / f for f in ("robot1.rrd", "robot2.rrd", "fusion.rrd")]
    assert all(_recording_ids(f) == {RECORDING_ID} for f in files)
    contents = read_recording(*files)
    assert contents.robots == ["robot1", "robot2"]
    assert contents.alignments["robot1_robot2"]["tx"] == 5.0
    assert contents.duration == pytest.approx(1.9)
    assert main(["review", *map(str, files), "--no-export"]) == 0
    assert "and 2 more file(s): 2 robot(s) (robot1, robot2)" in capsys.readouterr().out


@pytest.fixture
def saving_server(tmp_path):
    """The rerun CLI's server on a free loopback port, saving what it receives: (url, file)."""
    rerun_cli = Path(sys.executable).parent / "rerun"
    if not rerun_cli.exists():
        pytest.skip(f"no rerun CLI beside {sys.executable}")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    saved = tmp_path / "received.rrd"
    server = subprocess.Popen([str(rerun_cli), "--bind", "127.0.0.1", "--port", str(port), "--save", str(saved)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=_with_default_sigint)
    try:
        deadline = time.monotonic() + 30.0  # a loaded machine starts it in well under a second; margin 30x
        while time.monotonic() < deadline:
            with socket.socket() as probe:
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.1)
        else:
            pytest.fail("the rerun server did not start listening")
        yield f"rerun+http://127.0.0.1:{port}/proxy", saved, server
    finally:
        if server.poll() is None:
            server.kill()


def test_processes_streaming_to_one_endpoint_with_one_id_make_one_recording(saving_server):
    url, saved, server = saving_server
    _robot_processes(lambda robot: url)
    _log_fusion(url)
    server.send_signal(signal.SIGINT)  # the server finishes its file when it stops
    server.wait(timeout=60)
    assert _recording_ids(saved) == {RECORDING_ID}
    contents = read_recording(saved)
    assert contents.robots == ["robot1", "robot2"]
    assert contents.alignments["robot1_robot2"]["common"] == 9
