"""The camera-frame counts maps carry (metadata["slam_frames"], runtime/slam_frames.py) and what `p3at fuse` makes of
them: shown per map (text and --json), a warning for a starved run, older maps without them fused as before."""
from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest

from estimation.landmark_map import LandmarkMap
from runtime.cli import main
from runtime.slam_frames import STARVED_FRACTION, read_frame_counts, starved

_BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"

HEALTHY = {"received": 300, "processed": 296, "dropped": 4, "without_odometry": 0}
STARVED = {"received": 300, "processed": 60, "dropped": 200, "without_odometry": 40}


def test_counts_are_read_back_and_a_map_without_them_has_none():
    assert read_frame_counts({"slam_frames": dict(HEALTHY)}) == HEALTHY
    assert read_frame_counts({"true_start_pose": [0.0, 0.0, 0.0]}) is None


@pytest.mark.parametrize("bad", [[1, 2, 3, 4], {"received": 3, "processed": 3, "dropped": 0},
                                 {**HEALTHY, "extra": 1}, {**HEALTHY, "dropped": -1},
                                 {**HEALTHY, "processed": 2.5}, {**HEALTHY, "received": True},
                                 {**HEALTHY, "received": "300"}])
def test_malformed_counts_are_named(bad):
    with pytest.raises(ValueError, match="slam_frames"):
        read_frame_counts({"slam_frames": bad})


@pytest.mark.parametrize("bad", [{str(k): k for k in range(100_000)}, {**HEALTHY, "dropped": "9" * 100_000}])
def test_a_hostile_count_is_named_in_one_short_line(bad):
    with pytest.raises(ValueError, match="slam_frames") as raised:
        read_frame_counts({"slam_frames": bad})
    assert "\n" not in str(raised.value) and len(str(raised.value)) < 200


def test_a_run_is_starved_when_more_than_half_its_frames_were_not_mapped():
    assert starved(HEALTHY) is None
    assert starved({**HEALTHY, "processed": 0, "received": 0, "dropped": 0}) is None  # nothing to judge
    half = int(STARVED_FRACTION * 300)
    assert starved({"received": 300, "processed": 150, "dropped": half, "without_odometry": 0}) is None
    reason = starved({"received": 300, "processed": 149, "dropped": half, "without_odometry": 1})
    assert reason.startswith("151 of its 300 frames (50 %)") and "150 dropped" in reason and "1 without" in reason
    assert "40 without odometry" in starved(STARVED)


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    """Two overlapping simulated maps saved three ways: without counts (as before the key existed), one healthy
    and one starved run, and with a malformed key."""
    if str(_BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(_BENCHMARKS))
    sim = importlib.import_module("fusion_sim")
    d = tmp_path_factory.mktemp("frames")
    first, second = sim.building_pair(1.0, seed=5)
    for suffix, counts in (("old", None), ("new", (HEALTHY, STARVED)), ("bad", ({"received": -1}, HEALTHY))):
        for k, simulated in enumerate((first, second)):
            m = simulated.map
            metadata = {key: v for key, v in m.metadata.items() if key != "slam_frames"}
            if counts is not None:
                metadata["slam_frames"] = counts[k]
            m.metadata = metadata
            m.save(d / f"r{k + 1}-{suffix}.npz")
    return d


def _run(capsys, maps: Path, suffix: str, *extra: str) -> tuple[int, str, str]:
    status = main(["fuse", str(maps / f"r1-{suffix}.npz"), str(maps / f"r2-{suffix}.npz"), "--out",
                   str(maps / f"merged-{suffix}.npz"), *extra])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_fuse_shows_each_maps_frames_and_warns_of_the_starved_one(maps, capsys):
    status, out, err = _run(capsys, maps, "new")
    assert status == 0, err
    lines = out.splitlines()
    assert lines[0].endswith("; frames: 300 received, 296 mapped, 4 dropped, 0 without odometry)")
    assert lines[1].endswith("; frames: 300 received, 60 mapped, 200 dropped, 40 without odometry)")
    warnings = [line for line in err.splitlines() if "starved" in line]
    assert len(warnings) == 1 and warnings[0].startswith("p3at fuse: warning: map 1 (robot2) comes from a starved")
    assert "240 of its 300 frames (80 %)" in warnings[0]
    status, out, err = _run(capsys, maps, "new", "--json")
    assert status == 0, err
    report = json.loads(out)
    assert [m["slam_frames"] for m in report["maps"]] == [HEALTHY, STARVED]
    assert report["maps"][0]["starved"] is None and report["maps"][1]["starved"].startswith("240 of its 300")
    assert sum("starved" in line for line in err.splitlines()) == 1


def test_maps_without_counts_fuse_as_before_and_the_decision_does_not_depend_on_them(maps, capsys):
    status, out, err = _run(capsys, maps, "old")
    assert status == 0 and "frames:" not in out and "starved" not in err, err
    status, old, _ = _run(capsys, maps, "old", "--json")
    assert status == 0
    status, new, _ = _run(capsys, maps, "new", "--json")
    assert status == 0
    old, new = json.loads(old), json.loads(new)
    assert [m["slam_frames"] for m in old["maps"]] == [None, None]
    assert all(m["starved"] is None for m in old["maps"])
    assert old["alignments"] == new["alignments"] and old["merged_landmarks"] == new["merged_landmarks"]
    merged = LandmarkMap.load(maps / "merged-new.npz")  # a merged map keeps its reference map's metadata: its
    assert len(merged.robots) == 2                      # counts are not its own, and fuse does not show them
    # beside another run of robot2 (the merged map holds r2-new, whose estimates r2-old shares: fuse refuses those)
    another = importlib.import_module("fusion_sim").building_pair(1.0, seed=6)[1].map
    another.save(maps / "r2-another.npz")
    status = main(["fuse", str(maps / "merged-new.npz"), str(maps / "r2-another.npz"),
                   "--out", str(maps / "again.npz")])
    out = capsys.readouterr().out.splitlines()
    assert status == 0 and out and "frames:" not in out[0]


def test_a_malformed_count_is_one_note_and_the_maps_still_fuse(maps, capsys):
    status, out, err = _run(capsys, maps, "bad")
    assert status == 0, err
    notes = [line for line in err.splitlines() if "slam_frames" in line]
    assert len(notes) == 1 and notes[0].startswith("p3at fuse: note: ") and "r1-bad.npz" in notes[0]
    assert "frames:" not in out.splitlines()[0] and out.splitlines()[1].endswith("0 without odometry)")
