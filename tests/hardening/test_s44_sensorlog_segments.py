"""A sensor log folder that holds segments of more than one log (session 44, A): a segment copied beside the
others, two logs' segments in one folder, or a segment of another robot's log. Each is one line naming the segment,
exit 2. Before, ``p3at replay`` read them all in file-name order: a copied segment replayed its time a second time
(76 frames and 81 landmarks where the log has 38 and 76, a different final pose, exit 0) and another robot's segment
was silently skipped, its settings ignored."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.cli import main
from runtime.sensorlog import SensorLog, SensorLogError, SensorLogWriter
from tests.runtime.test_sensorlog_mcap import GEOMETRY, _records


def _log(folder: Path, robot: str = "robot1", seed: int = 1, start: float = 50.0) -> list[Path]:
    """A log of three or more 2 s segments (60 SIPs over 6 s); the segment files in order."""
    with SensorLogWriter(folder, {"robot": robot, "geometry": GEOMETRY, "seed": seed}, segment_seconds=2.0) as w:
        for stream, record in _records(60, np.random.default_rng(seed), images=False, start=start):
            w.write(stream, record)
    assert len(w.segments) >= 3
    return list(w.segments)


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, list[Path]]:
    root = tmp_path_factory.mktemp("logs")
    return {"robot1": _log(root / "robot1-log"), "robot2": _log(root / "robot2-log", "robot2", seed=2),
            "later": _log(root / "later-log", start=500.0)}


def _folder(tmp_path: Path, files: list[tuple[Path, str]]) -> Path:
    folder = tmp_path / "log"
    folder.mkdir()
    for source, name in files:
        shutil.copy(source, folder / name)
    return folder


def _refused(folder: Path, capsys, *words: str) -> None:
    with pytest.raises(SensorLogError) as error:
        SensorLog(folder)
    assert all(w in str(error.value) for w in words), str(error.value)
    assert main(["replay", str(folder)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err and str(folder) in err


def test_the_whole_log_and_its_renamed_copy_read(logs, tmp_path):
    """What the checks must let through: the writer's own folder, and its segments under another name."""
    whole = SensorLog(logs["robot1"][0].parent)
    renamed = SensorLog(_folder(tmp_path, [(p, f"copy_{k}.mcap") for k, p in enumerate(logs["robot1"])]))
    assert renamed.counts == whole.counts and len(renamed.files) == len(logs["robot1"])


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_copied_segment_is_refused(logs, tmp_path_factory, capsys, data):
    """Any segment copied in as the next one (or in the middle, renumbering those after it) replays time
    backwards."""
    segments = logs["robot1"]
    k = data.draw(st.integers(0, len(segments) - 1), label="copied segment")
    at = data.draw(st.integers(k + 1, len(segments)), label="inserted before")
    order = segments[:at] + [segments[k]] + segments[at:]
    folder = _folder(tmp_path_factory.mktemp("copy"), [(p, f"r_{i}.mcap") for i, p in enumerate(order)])
    _refused(folder, capsys, "no later than")


def test_two_logs_in_one_folder_are_refused(logs, tmp_path, capsys):
    """Both logs' segments keep their names: two segments numbered 0."""
    folder = _folder(tmp_path, [(p, p.name) for p in logs["robot1"] + logs["robot2"]])
    _refused(folder, capsys, "two segments numbered 0")


@pytest.mark.parametrize("other", ["robot2", "later"])
def test_a_segment_of_another_log_is_refused(logs, tmp_path, capsys, other):
    """Another robot's segment (its settings differ), or the same robot's later log with the same settings but
    numbered as if it were the next segment: refused either way (settings, or the order of its times)."""
    files = [(p, f"r_{i}.mcap") for i, p in enumerate(logs["robot1"])]
    files.append((logs[other][0], f"r_{len(files)}.mcap"))
    folder = _folder(tmp_path, files)
    if other == "robot2":
        _refused(folder, capsys, "settings differ")
    else:   # a later log of the same robot and settings continues in time: nothing in it says it is another
        assert SensorLog(folder).files[-1].name == f"r_{len(files) - 1}.mcap"


def test_a_frame_whose_images_differ_in_size_names_the_file_and_frame(tmp_path, capsys):
    """A stereo frame whose left and right images differ in size (a damaged or hand-made log): one line naming the
    segment and the frame, exit 2 as for any bad log. Before, the front end refused it with 'left (48, 64) and
    right (24, 32) images differ in size', naming no file, and replay exited 1 as if the machine had failed."""
    folder = tmp_path / "robot1-log"
    with SensorLogWriter(folder, {"robot": "robot1", "geometry": GEOMETRY, "seed": 3}) as w:
        for stream, record in _records(30, np.random.default_rng(3), images=True):
            if stream == "frames" and record["seq"] == 10:
                record = {**record, "right": record["right"][:24, :32]}
            w.write(stream, record)
    assert main(["replay", str(folder), "--every-frame"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "robot1-log_0.mcap: the frame at" in err[0] and "64x48" in err[0] and "32x24" in err[0]


def _observation_log(folder: Path, change) -> Path:
    with SensorLogWriter(folder, {"robot": "robot1", "geometry": GEOMETRY, "seed": 4}) as w:
        for stream, record in _records(40, np.random.default_rng(4), images=False):
            if stream == "observations" and len(record["points"]):
                record = change(dict(record))
            w.write(stream, record)
    return folder


def _negative(r):
    return {**r, "covariances": -np.tile(np.eye(3), (len(r["points"]), 1, 1))}


def _asymmetric(r):   # symmetrised as the filter does: eigenvalues 3.5, 1, -1.5
    c = np.tile(np.eye(3), (len(r["points"]), 1, 1))
    c[:, 0, 1] = 5.0
    return {**r, "covariances": c}


def _short_descriptors(r):
    return {**r, "descriptors": np.zeros((len(r["points"]), 7), np.float32)}


@pytest.mark.parametrize(("change", "words"), [(_negative, "not positive semi-definite"),
                                               (_asymmetric, "not positive semi-definite"),
                                               (_short_descriptors, "7-element descriptors")],
                         ids=["negative", "asymmetric", "descriptors"])
def test_observations_the_filter_cannot_take_are_a_bad_log(tmp_path, capsys, change, words):
    """Before, FastSLAM refused them ('an observation covariance is not positive definite', 'observations carry
    7-element descriptors; the filter was configured for descriptor_size=64'), naming no file, exit 1."""
    folder = _observation_log(tmp_path / "robot1-log", change)
    assert main(["replay", str(folder), "--every-frame", "--particles", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and str(folder) in err[0], err


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(factor=st.lists(st.floats(-3, 3), min_size=9, max_size=9), rank=st.integers(1, 3))
def test_any_semidefinite_covariance_passes_the_reader(tmp_path_factory, factor, rank):
    """A Aᵀ of any rank (a zero, a flat, a full ellipsoid) is read as written."""
    a = np.array(factor).reshape(3, 3)[:, :rank]
    cov = a @ a.T

    def change(r):
        return {**r, "covariances": np.tile(cov, (len(r["points"]), 1, 1))}

    log = SensorLog(_observation_log(tmp_path_factory.mktemp("psd") / "robot1-log", change))
    for record in log.records("observations"):
        if len(record["points"]):
            np.testing.assert_array_equal(record["covariances"][0], cov)
