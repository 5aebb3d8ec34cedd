"""End to end on the virtual hardware: the two-robot mission, its recording, replay, and clean shutdown.

Everything runs the real code paths: virtual P3-ATs served over TCP and driven by the real ARCOS driver,
the onboard threads, FastSLAM, the map exchange, fusion, Rerun to a file, sensor logs. The camera is the
synthetic observer (rendering two heads would not fit the test budget); one test runs the rendering virtual
head through the Videre driver and the front end.
"""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.cli import main
from runtime.fleet.processes import free_port
from runtime.json_output import json_text
from runtime.mission import Mission, MissionConfig
from runtime.replay import replay_log
from runtime.rerun_read import RecordingReadError, read_recording
from runtime.sensorlog import SensorLog

REPO = Path(__file__).resolve().parents[2]


def _with_default_sigint() -> None:
    """preexec_fn: the child gets SIGINT as a terminal's Ctrl-C would, whatever this test process inherited
    (an ignored or blocked SIGINT is inherited across exec, and then Ctrl-C could not stop the child)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture(scope="module")
def mission(tmp_path_factory):
    out = tmp_path_factory.mktemp("mission")
    # simulated time (the default on virtual hardware): the answer does not depend on the machine's load
    config = MissionConfig(robots=2, seconds=30.0, seed=3, camera="synthetic", camera_rate=10.0, particles=50,
                           fusion_interval=10.0, out=out, rerun="file", log_sensors=True)
    result = Mission(config).run()
    return config, result


def _outcome(summary: dict) -> dict:
    """The summary's figures that are the mission's answer (not its timings, paths or wall seconds)."""
    robots = {name: {k: r[k] for k in ("landmarks", "frames_received", "frames_processed", "frames_dropped",
                                       "frames_without_odometry", "final_position_error", "odometry_position_error")}
              for name, r in summary["robots"].items()}
    fusion = summary["fusion"]
    return json.loads(json.dumps({"robots": robots, "duration": summary["duration"], "failures": summary["failures"],
                                  "pairs": fusion["pairs"], "merged": fusion["merged_landmarks"]}))


@pytest.mark.slow
def test_one_seed_gives_identical_maps_and_figures_alone_and_beside_busy_processes(tmp_path):
    """The two-robot mission twice with one seed, the second time with two busy-loop processes competing for the
    CPU: every array of every map file is the same, and so are the alignment figures (simulated time waits for
    the slowest stage). Short (10 simulated seconds, enough for a first alignment, found once and not yet confirmed by
    a later fusion: fusion/confirmation.py) to keep the suite fast. The sensor logs are the same message for message,
    their last records (the stop's, in simulated time: test_mission_stop.py) too."""
    config = MissionConfig(robots=2, seconds=10.0, seed=5, camera="synthetic", camera_rate=10.0, particles=30,
                           fusion_interval=5.0, out=tmp_path / "alone", rerun="none", odometry="realistic",
                           log_sensors=True)
    first = Mission(config).run()
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        second = Mission(dataclasses.replace(config, out=tmp_path / "busy")).run()
    finally:
        for process in busy:
            process.kill()
            process.wait()
    pair = first.summary["fusion"]["pairs"][0]   # found by the evidence; 10 s is too short to confirm it (a candidate)
    assert pair["aligned"] or pair["note"].startswith("candidate"), pair["note"]
    assert pair["supports"] >= pair["required_supports"] > 0
    assert [r.as_dict()["pairs"] for r in first.fusion_history] == [r.as_dict()["pairs"] for r in
                                                                      second.fusion_history]
    for name in ("robot1.npz", "robot2.npz", "fused.npz"):
        with np.load(config.out / name) as a, np.load(tmp_path / "busy" / name) as b:
            assert a.files == b.files
            for key in a.files:
                assert np.array_equal(a[key], b[key]), f"{name}: {key} differs"
    np.testing.assert_equal(_outcome(second.summary), _outcome(first.summary))
    assert second.summary["clock"] == "simulated" and not second.failures
    for name in ("robot1", "robot2"):
        alone, busy_log = SensorLog(config.out / f"{name}-log"), SensorLog(tmp_path / "busy" / f"{name}-log")
        assert alone.counts == busy_log.counts, name
        assert [(m.topic, m.log_time, m.data) for m in alone.messages()] == \
            [(m.topic, m.log_time, m.data) for m in busy_log.messages()], name


@pytest.mark.slow
def test_two_robots_build_two_maps_and_their_fusion_is_aligned(mission):
    config, result = mission
    summary = result.summary
    assert sorted(result.maps) == ["robot1", "robot2"]
    for name, m in result.maps.items():
        # 30 simulated seconds: the robots have met in the corridor but not passed each other yet (robot2 has
        # mapped ~40 landmarks by then, ~50 at 45 s); every frame is processed in simulated time (10 Hz)
        assert len(m) > 30, f"{name} mapped only {len(m)} landmarks"
        assert summary["robots"][name]["frames_processed"] == summary["robots"][name]["frames_received"] > 250
        # each map is in its own start frame and says where that was, for scoring
        assert m.metadata["true_start_pose"] is not None
        saved = LandmarkMap.load(config.out / f"{name}.npz")
        np.testing.assert_array_equal(saved.positions, m.positions)
    (pair,) = summary["fusion"]["pairs"]
    assert pair["aligned"], pair["note"]
    # typically 0.01-0.04 m, but the maps' own heading drift (thread timing differs run to run) sometimes makes
    # it 0.4 m / 0.08 rad; a false alignment here is about 5 m / 3 rad off (the truth is (5, 0, π))
    assert pair["error_xy"] < 0.6 and pair["error_theta"] < 0.15, pair
    assert pair["common"] >= 6  # several landmarks both robots mapped (the robust preset accepts from 4)
    merged = result.fused
    assert len(merged) == summary["fusion"]["merged_landmarks"]
    assert max(len(m) for m in result.maps.values()) < len(merged) < sum(len(m) for m in result.maps.values())
    assert merged.seen_by.all(axis=1).sum() == pair["common"]  # the common landmarks carry both robots


@pytest.mark.slow
def test_each_saved_map_carries_its_robots_frame_counts(mission):
    """metadata["slam_frames"]: the counts of the mission's summary, in the file and in the map it returned."""
    config, result = mission
    for name, robot in result.summary["robots"].items():
        want = {"received": robot["frames_received"], "processed": robot["frames_processed"],
                "dropped": robot["frames_dropped"], "without_odometry": robot["frames_without_odometry"]}
        assert LandmarkMap.load(config.out / f"{name}.npz").metadata["slam_frames"] == want
        assert result.maps[name].metadata["slam_frames"] == want and want["processed"] > 250


@pytest.mark.slow
def test_the_recording_plots_the_landmarks_of_the_exported_map_the_summary_counts(mission):
    """The progress line, the fleet status and the summary count the exported map (FastSLAM.best_map: confirmed
    landmarks, coincident ones merged); the recording's per-frame counts are the best particle's own. Each snapshot's
    count is plotted beside them, and the last (the snapshot taken when the robot stops) is the summary's."""
    from runtime.rerun_style import SERIES

    from .rerun_helpers import entity_rows

    config, result = mission
    for name, robot in result.summary["robots"].items():
        rows = [r for r in entity_rows(config.out / "mission.rrd", f"plots/{name}/landmarks/map")
                if r.get("Scalars:scalars") is not None]
        assert len(rows) >= 6  # a snapshot every 5 s of 30 s, and one at the stop
        last = max(rows, key=lambda r: r["sim_time"])
        assert last["Scalars:scalars"] == [float(robot["landmarks"])]
        assert robot["landmarks"] == len(result.maps[name]) > 30
    assert "exported map" in SERIES["landmarks/map"][0] and "merge" in SERIES["landmarks/confirmed"][0]


@pytest.mark.slow
def test_the_summary_lists_every_file_the_mission_left(mission):
    config, result = mission
    listed = {Path(f) for f in result.summary["files"]}
    assert listed == set(config.out.iterdir())  # nothing unlisted, nothing listed that is not there
    for name in ("robot1", "robot2"):
        assert {config.out / f"{name}{suffix}" for suffix in (".npz", ".ply", ".tum", "-odometry.tum", "-truth.tum",
                                                             "-log")} <= listed
    ply = (config.out / "robot1.ply").read_bytes()
    assert ply.startswith(b"ply\n") and f"element vertex {len(result.maps['robot1'])}".encode() in ply


@pytest.mark.slow
def test_review_reads_the_recording_back_with_the_same_figures(mission, tmp_path, capsys):
    config, result = mission
    rrd = config.out / "mission.rrd"
    assert main(["review", str(rrd), "--json", "--export", str(tmp_path)]) == 0
    review = json.loads(capsys.readouterr().out)
    assert review["robots"] == ["robot1", "robot2"]
    assert review["maps"] == {"fused": len(result.fused), "robot1": len(result.maps["robot1"]),
                              "robot2": len(result.maps["robot2"])}
    # a failed alignment's figures are NaN in the summary, null in the strict JSON the review prints
    np.testing.assert_equal(review["mission_summary"], json.loads(json_text(result.summary)))
    alignment = review["alignments"]["robot1_robot2"]
    final = result.summary["fusion"]["pairs"][0]
    np.testing.assert_equal([alignment[k] for k in ("tx", "ty", "theta")], [final[k] for k in ("tx", "ty", "theta")])
    # the recording ends with the mission: nothing of the shutdown (whose simulated length grows with the machine's
    # load: 3.3 s over 30 s seen in a loaded run) is stamped after the stop
    assert review["duration"] == pytest.approx(result.summary["duration"], abs=0.05)
    for name, m in result.maps.items():  # the exported maps are the robots' maps, array for array
        exported = LandmarkMap.load(tmp_path / f"{name}.npz")
        np.testing.assert_array_equal(exported.positions, m.positions)
        np.testing.assert_array_equal(exported.covariances, m.covariances)
        np.testing.assert_array_equal(exported.descriptors, m.descriptors)
        np.testing.assert_array_equal(exported.ids, m.ids)
        assert exported.metadata["true_start_pose"] == m.metadata["true_start_pose"]


@pytest.mark.slow
def test_replay_of_the_sensor_log_rebuilds_the_live_map(mission, tmp_path, capsys):
    config, result = mission
    for name in ("robot1", "robot2"):
        log = SensorLog(config.out / f"{name}-log")
        assert log.closed and log.count("odometry") > 100 and log.count("observations") > 100
        replayed = replay_log(config.out / f"{name}-log")
        live = result.maps[name]
        for field in ("ids", "positions", "covariances", "descriptors", "counts", "seen_by", "trajectory"):
            np.testing.assert_array_equal(getattr(replayed.landmark_map, field), getattr(live, field), err_msg=field)
        assert replayed.missing_frames == 0
    # the command line, with other parameters, gives another (valid) map
    out = tmp_path / "other.npz"
    assert main(["replay", str(config.out / "robot1-log"), "--particles", "5", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["particles"] == 5 and summary["landmarks"] == len(LandmarkMap.load(out)) > 0


def test_review_and_replay_refuse_bad_input_with_a_clear_message(tmp_path, capsys):
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording")
    with pytest.raises(RecordingReadError, match="bad.rrd"):
        read_recording(bad)
    assert main(["review", str(bad)]) == 2  # a bad file: one line, exit 2
    assert main(["replay", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "bad.rrd" in err and "no sensor log here" in err


def test_sigterm_mid_run_stops_the_robot_and_leaves_readable_files(tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    process = subprocess.Popen(
        [sys.executable, "-m", "runtime.cli", "run", "--camera", "synthetic", "--seconds", "120", "--particles",
         "20", "--map-save-interval", "1", "--out", str(out), "--log-sensors", "--quiet", "--json"],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # mid-run is an event, not a wall-clock delay: the first map save, 1 simulated second in (the handler is
        # installed before the mission starts, and the robot has driven and logged odometry by then). The deadline
        # only bounds a broken run (start-up takes seconds on a loaded machine).
        deadline = time.monotonic() + 120
        while not (out / "robot1.npz").exists():
            assert process.poll() is None and time.monotonic() < deadline, "no map saved mid-run"
            time.sleep(0.05)
        process.send_signal(signal.SIGTERM)
        stdout, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, stderr
    summary = json.loads(stdout)
    assert summary["duration"] < 60  # it stopped early, on the signal
    log = SensorLog(out / "robot1-log")
    assert log.closed and log.count("odometry") > 0
    final_speed = [float(r["v"]) for r in log.records("odometry")][-1]
    assert abs(final_speed) < 0.05  # the motors were stopped before the log was closed
    assert len(LandmarkMap.load(out / "robot1.npz")) == summary["robots"]["robot1"]["landmarks"]
    assert read_recording(out / "mission.rrd").maps["robot1"] is not None


def test_rendered_stereo_head_through_the_videre_driver_feeds_the_pipeline_and_replays(tmp_path):
    config = MissionConfig(robots=1, seconds=4.0, camera="mock", camera_rate=7.5, particles=10, motion="none",
                           fusion_interval=0.0, out=tmp_path, rerun="none", log_sensors=True)
    result = Mission(config).run()
    robot = result.summary["robots"]["robot1"]
    assert robot["frames_processed"] >= 3
    assert robot["landmarks"] > 20  # corners on the rendered walls, triangulated and mapped
    assert robot["ms_per_frame"]["frontend"] > 0
    # simulated time: every frame reaches the driver exactly `latency` after its exposure, none is dropped
    assert robot["frames_late"] == 0 and robot["frames_dropped_at_head"] == {}
    assert robot["frames_dropped"] == robot["frames_without_odometry"] == 0
    from runtime.report import format_summary

    assert " late " in format_summary(result.summary).splitlines()[2]
    log = SensorLog(tmp_path / "robot1-log")
    frame = next(log.records("frames"))
    assert frame["left"].shape == frame["right"].shape == (480, 640) and frame["left"].dtype == np.uint8
    replayed = replay_log(tmp_path / "robot1-log")  # images through the same front end settings: same map
    np.testing.assert_array_equal(replayed.landmark_map.positions, result.maps["robot1"].positions)


def _wait_until(condition, bound: float = 60.0) -> bool:
    """Poll ``condition`` until it holds; ``bound`` (wall s) only limits how long a broken run hangs."""
    end = time.monotonic() + bound
    while not condition() and time.monotonic() < end:
        time.sleep(0.02)
    return bool(condition())


def test_a_slow_slam_stage_drops_frames_and_says_so_without_blocking_the_drivers():
    """The SLAM stage at its slowest, stuck on a frame until the test lets it go: the camera thread keeps taking
    frames (the queue's oldest dropped, counted, reported) and the driver keeps delivering odometry. Everything
    is awaited as a condition: no count depends on how much CPU a loaded machine gives each thread."""
    import threading

    from drivers.arcos.robot import P3AT
    from estimation.fastslam import FastSLAMConfig
    from mocks.p3at import serve_tcp
    from mocks.synthetic_stereo import SyntheticStereo
    from mocks.world import World
    from runtime.adapters import P3ATLink, SyntheticCamera
    from runtime.onboard import Onboard, OnboardConfig

    world = World.load()
    events: list[str] = []
    with serve_tcp(world, "robot1", port=0, seed=1) as server:
        driver = P3AT(server.url)
        driver.connect()
        link = P3ATLink(driver)
        camera = SyntheticCamera(SyntheticStereo.from_world(world, np.random.default_rng(2)),
                                 lambda: world.pose("robot1"), rate=60.0)
        onboard = Onboard("robot1", link, camera, OnboardConfig(fastslam=FastSLAMConfig(n_particles=10)),
                          on_event=events.append)
        step = onboard.core.step
        stuck, release = threading.Event(), threading.Event()
        odometry_when_stuck: list[int] = []

        def stuck_step(frame, pose):
            if not stuck.is_set():
                odometry_when_stuck.append(onboard.stats.odometry_samples)
                stuck.set()
            release.wait(120.0)
            return step(frame, pose)

        onboard.core.step = stuck_step
        onboard.start()
        try:
            assert _wait_until(stuck.is_set), "no frame reached the SLAM stage"
            # 20 SIPs (2 s of the robot's 10 Hz) arrive while the SLAM stage holds its frame; a reader held up by
            # it would deliver none
            assert _wait_until(lambda: onboard.stats.odometry_samples >= odometry_when_stuck[0] + 20
                               and onboard.stats.dropped_frames > 0), onboard.stats
            release.set()
            assert _wait_until(lambda: onboard.stats.frames_processed > 0), onboard.stats
        finally:
            release.set()
            onboard.stop()
        stats = onboard.stats
        link.close()
    assert stats.dropped_frames > 0 and any("dropped frame" in e for e in events)
    assert stats.frames_received >= stats.frames_processed + stats.dropped_frames


def test_run_on_a_real_robot_url_without_a_stereo_head_fails_cleanly(tmp_path, capsys):
    """No head on USB (no libusb, or no device): one line naming the head, exit 1, the robot's motors never enabled
    (the head is looked for before the robot is connected, e47d0e7)."""
    from mocks.p3at import serve_tcp
    from mocks.world import World

    world = World.load()
    with serve_tcp(world, "robot1", port=0, seed=1) as server:
        status = main(["run", "--robot", server.url, "--seconds", "2", "--out", str(tmp_path), "--quiet"])
        motors = server.model.motors_enabled
    err = capsys.readouterr().err
    assert status == 1 and not motors
    assert "stereo head" in err and len(err.strip().splitlines()) == 1


def _head_found_by_the_check(monkeypatch):
    """The run's look for the head finds one, which is gone when the mission opens it (unplugged in between)."""
    monkeypatch.setattr("runtime.commands.run.usb_head_problem", lambda: None)


@pytest.fixture
def rerun_server(tmp_path):
    """The rerun CLI's headless server on a free loopback port, saving what it receives: (port, file)."""
    import socket

    rerun_cli = Path(sys.executable).parent / "rerun"
    if not rerun_cli.exists():
        pytest.skip(f"no rerun CLI beside {sys.executable}")
    port = free_port()
    saved = tmp_path / "received.rrd"
    server = subprocess.Popen([str(rerun_cli), "--bind", "127.0.0.1", "--port", str(port), "--save", str(saved)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=_with_default_sigint)
    try:
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:  # wait until it listens
            with socket.socket() as probe:
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.1)
        else:
            pytest.fail("the rerun server did not start listening")
        yield port, saved
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()


def test_a_mission_streams_live_to_a_running_rerun_server(rerun_server, tmp_path):
    """``--rerun rerun+http://...``: the mission connects to a running Rerun server and everything arrives."""
    port, saved = rerun_server
    config = MissionConfig(robots=1, seconds=4.0, seed=1, camera="synthetic", camera_rate=10.0, particles=20,
                           fusion_interval=0.0, out=tmp_path / "out",
                           rerun=f"rerun+http://127.0.0.1:{port}/proxy")
    result = Mission(config).run()
    deadline = time.monotonic() + 30.0  # the server writes what it received in its own time (a loaded machine)
    while True:
        try:
            contents = read_recording(saved)
            if contents.summary is not None or time.monotonic() > deadline:
                break
        except RecordingReadError:
            if time.monotonic() > deadline:
                raise
        time.sleep(0.2)
    assert contents.robots == ["robot1"]
    assert contents.summary is not None
    assert len(contents.maps["robot1"]) == len(result.maps["robot1"]) > 0


def test_spawn_reuses_a_viewer_already_listening_on_loopback(rerun_server):
    from runtime.rerun_sink import spawn_viewer

    port, _ = rerun_server
    assert spawn_viewer(port, timeout=2.0) == f"rerun+http://127.0.0.1:{port}/proxy"


def test_spawn_on_a_machine_without_a_display_fails_before_the_robots_start(tmp_path, capsys, monkeypatch):
    for variable in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.setattr("runtime.rerun_sink.VIEWER_PORT", free_port())
    status = main(["demo", "--rerun", "spawn", "--camera", "synthetic", "--seconds", "2", "--out", str(tmp_path),
                   "--quiet"])
    assert status == 1
    assert "Rerun viewer exited at start" in capsys.readouterr().err
    assert not (tmp_path / "robot1.npz").exists()


def _failing_slam(monkeypatch, robot: str, after_frames: int) -> None:
    """From its ``after_frames``-th frame on, ``robot``'s FastSLAM update raises what the proposal's Cholesky
    factorisation raised in the field."""
    from runtime.onboard import SlamCore

    step = SlamCore.step

    def step_that_fails(self, frame, pose):
        if self.robot == robot and self.frames >= after_frames:
            def update(observations):
                raise np.linalg.LinAlgError("Matrix is not positive definite")
            self.slam.update = update
        return step(self, frame, pose)

    monkeypatch.setattr(SlamCore, "step", step_that_fails)


def test_a_stage_that_raises_stops_its_robot_and_ends_the_mission_with_the_reason(tmp_path, monkeypatch):
    _failing_slam(monkeypatch, "robot2", after_frames=20)
    events: list[str] = []
    config = MissionConfig(robots=2, seconds=30.0, seed=1, camera="synthetic", camera_rate=10.0, particles=10,
                           fusion_interval=0.0, out=tmp_path, rerun="none", log_sensors=True)
    result = Mission(config, events=events.append).run()
    (failure,) = result.failures
    assert (failure.robot, failure.stage) == ("robot2", "slam") and "LinAlgError" in failure.error
    # reported at once (the event line), and the mission ended at that simulated instant (its loop ticks at 0.2 s)
    assert any("robot2" in e and "slam stage failed" in e and "LinAlgError" in e for e in events)
    assert failure.t - 0.001 <= result.summary["sim_seconds"] <= failure.t + 0.2  # (the summary rounds to ms)
    assert result.summary["failures"] == [{"robot": "robot2", "stage": "slam", "error": failure.error,
                                           "t": failure.t}]
    assert result.summary["robots"]["robot2"]["frames_processed"] == 20  # the 21st frame raised
    last = [r for r in SensorLog(tmp_path / "robot2-log").records("odometry")][-1]
    assert abs(float(last["v"])) < 0.01 and abs(float(last["w"])) < 0.01  # its motors were stopped
    assert LandmarkMap.load(tmp_path / "robot2.npz") is not None  # what it had mapped is kept


def test_the_command_line_exits_non_zero_naming_robot_stage_and_error(tmp_path, monkeypatch, capsys):
    _failing_slam(monkeypatch, "robot1", after_frames=5)
    status = main(["demo", "--camera", "synthetic", "--camera-rate", "10", "--seconds", "20", "--particles", "10",
                   "--rerun", "none", "--out", str(tmp_path), "--quiet"])
    captured = capsys.readouterr()
    assert status == 1
    assert "mission failed: robot1: the slam stage failed" in captured.err and "LinAlgError" in captured.err
    assert "FAILED stages" in captured.out  # and a row in the summary table


def test_a_killed_demo_leaves_readable_maps(tmp_path):
    """SIGKILL mid-mission (no handler runs): the maps written every --map-save-interval simulated seconds are
    whole files, since each is written to a temporary file and renamed."""
    out = tmp_path / "demo"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    process = subprocess.Popen(
        [sys.executable, "-m", "runtime.cli", "demo", "--camera", "synthetic", "--camera-rate", "10", "--seconds",
         "600", "--particles", "10", "--map-save-interval", "1", "--rerun", "none", "--out", str(out), "--quiet"],
        cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        maps = []
        while time.monotonic() < deadline and len(maps) < 2:
            maps = sorted(out.glob("robot*.npz"))
            time.sleep(0.1)
        assert len(maps) == 2, "no maps were saved during the mission"
        first = {p: p.stat().st_mtime_ns for p in maps}
        while time.monotonic() < deadline and all(p.stat().st_mtime_ns == first[p] for p in maps):
            time.sleep(0.02)  # kill while the saves go on, at no particular moment
        process.kill()
        process.wait(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == -signal.SIGKILL
    for path in sorted(out.glob("*.npz")):
        saved = LandmarkMap.load(path)
        assert len(saved) > 0, path
        if path.name.startswith("robot"):  # the periodic saves carry the frame counts of their moment
            assert 0 < saved.metadata["slam_frames"]["processed"] <= saved.metadata["slam_frames"]["received"]


def test_a_run_that_fails_at_start_keeps_the_earlier_recording(tmp_path, capsys, monkeypatch):
    """`p3at run` on a robot it cannot set up (here: a stereo head gone when the mission opens it) used to replace an
    earlier run's mission.rrd with an empty recording before failing; the new recording now takes the name only once
    every robot is up."""
    from mocks.p3at import serve_tcp
    from mocks.world import World

    _head_found_by_the_check(monkeypatch)

    earlier = tmp_path / "mission.rrd"
    earlier.write_bytes(b"the first run's recording")
    with serve_tcp(World.load(), "robot1", port=0, seed=1) as server:
        status = main(["run", "--robot", server.url, "--seconds", "2", "--out", str(tmp_path), "--quiet"])
    assert status == 1 and "mission failed" in capsys.readouterr().err
    assert earlier.read_bytes() == b"the first run's recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mission.rrd"]


def test_a_run_that_starts_replaces_the_earlier_recording(tmp_path):
    """Once the robots are up the new recording is mission.rrd, whole and readable, and no temporary file is left."""
    from runtime.rerun_read import read_recording

    earlier = tmp_path / "mission.rrd"
    earlier.write_bytes(b"the first run's recording")
    status = main(["demo", "--camera", "synthetic", "--robots", "1", "--seconds", "2", "--quiet",
                   "--out", str(tmp_path)])
    assert status == 0
    contents = read_recording(earlier)
    assert contents.robots == ["robot1"] and contents.ended and contents.summary is not None
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".mission.rrd")]
