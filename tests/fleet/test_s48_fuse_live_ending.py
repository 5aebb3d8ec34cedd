"""``p3at fuse --live``'s ending in text mode and its ``--recording-id`` (session 48, helper D's walkthrough).

It ended with ``24 fusions; the last: {...}``, one ~900-character line of JSON, and never said where it wrote the
fused map or the recording; and it had no ``--recording-id``, so the node's recording of a fleet started by hand
could not be read with the robots' (``p3at review fusion.rrd r1/mission.rrd ...`` refused: another recording).
Processes on loopback (random free ports); waits have deadlines far above what they need; nothing asserts a duration.
"""
from __future__ import annotations

import os
import subprocess
import warnings
from pathlib import Path

import pytest

pytest.importorskip("zenoh")

from estimation.landmark_map import LandmarkMap  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.report import alignment_text  # noqa: E402
from runtime.rerun_read import read_recording  # noqa: E402
from tests.fleet.live_node import endpoint, p3at, stopped_after_first_fusion  # noqa: E402

pytestmark = pytest.mark.timeout(180)
RECORDING_ID = "s48-hand-started-fleet"


def recording_ids(path: Path) -> set[str]:
    import rerun.chunk as rrchunk

    with warnings.catch_warnings():   # a file without Rerun's footer is read by scanning
        warnings.simplefilter("ignore")
        return {str(store.recording_id) for store in rrchunk.RrdReader(path).recordings()}


def test_the_nodes_recording_carries_the_recording_id_given(tmp_path):
    """No robot: the node ends after --seconds with nothing to fuse (exit 1), its recording written under the id."""
    port, fleet = free_port(), f"rid{os.getpid()}"
    saved = tmp_path / "node" / "fusion.rrd"
    node = p3at("fuse", "--live", "--exchange", endpoint("listen", port), "--fleet", fleet, "--seconds", "1",
                "--rerun", str(saved), "--recording-id", RECORDING_ID, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout, stderr = node.communicate(timeout=120)
    assert node.returncode == 1, stderr
    assert recording_ids(saved) == {RECORDING_ID}
    # the recording is named, with the commands that read it, and with the robots' files of the same id
    assert stdout.splitlines() == [
        f"Rerun recording: {saved}", f"  open it with:   rerun {saved}", f"  summarise it:   p3at review {saved}",
        f"  with the robots' (p3at run --recording-id {RECORDING_ID}): p3at review {saved} ROBOT/mission.rrd ..."
    ], stdout


def test_without_a_recording_id_the_node_takes_a_new_one(tmp_path):
    port, fleet = free_port(), f"nid{os.getpid()}"
    saved = tmp_path / "fusion.rrd"
    node = p3at("fuse", "--live", "--exchange", endpoint("listen", port), "--fleet", fleet, "--seconds", "1",
                "--rerun", str(saved), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout, stderr = node.communicate(timeout=120)
    assert node.returncode == 1, stderr
    (found,) = recording_ids(saved)
    assert found != RECORDING_ID
    assert stdout.splitlines()[-1] == f"  summarise it:   p3at review {saved}", stdout


def test_p3at_fuse_live_ends_with_the_last_fusion_in_words_the_fused_map_and_the_recording(tmp_path):
    """Text mode, stopped by SIGTERM after its first fusion (as Ctrl-C): the last fusion's pair in p3at review's
    words (the figures the recording's summary holds), the fused map's landmarks and file, the recording's file."""
    port, fleet = free_port(), f"end{os.getpid()}"
    out, saved = tmp_path / "fused.npz", tmp_path / "fusion.rrd"
    node = p3at("fuse", "--live", "--exchange", endpoint("listen", port), "--fleet", fleet, "--seconds", "120",
                "--interval", "1", "--out", str(out), "--rerun", "file", stdout=subprocess.PIPE,
                stderr=subprocess.PIPE)
    stdout, stderr = stopped_after_first_fusion(node, port, fleet)
    assert node.returncode == 0, stderr
    assert "{" not in stdout, stdout   # no raw JSON
    summary = read_recording(saved).summary
    final = summary["fusion"]
    pair = final["pairs"][0]
    assert pair["aligned"], pair
    merged = LandmarkMap.load(out)
    assert len(merged) == final["merged_landmarks"]
    text = " ".join(stdout.split())   # the pair's line may be wrapped
    fusions = summary["fusions"]
    assert stdout.startswith(f"{fusions} fusion{'' if fusions == 1 else 's'}; the last, at t={final['t']:.0f} s:\n")
    assert f"robot2 -> robot1: {' '.join(alignment_text(pair).split())}" in text, stdout
    assert stdout.splitlines()[-4:] == [
        f"Fused map: {len(merged)} landmarks -> {out}", f"Rerun recording: {saved}",
        f"  open it with:   rerun {saved}", f"  summarise it:   p3at review {saved}"], stdout
