"""Readings repeated word for word (estimation.datasets.repeats, ``p3at slam dataset --drop-repeats``): a sighting
whose range and bearing equal its landmark's previous reading is the camera's held reading, one measurement; it is
dropped and its first report kept at its own stamp (with ``images``, the other readings of its image too), and nothing
else in the log moves."""
from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.datasets import RangeBearingLog, drop_repeated_readings, read_mrclam, repeated_readings

from .conftest import run_cli

ODOMETRY = np.array([[0.0, 0.0, 0.0, 0.0], [100.0, 1.0, 0.0, 0.0]])
TRUTH = np.array([[0.0, 0.5, 0.5, 0.1], [100.0, 1.5, 0.5, 0.1]])


@st.composite
def logs_with_repeats(draw):
    """(log, injected (N,) bool): sightings of a few landmarks from a small pool of readings (so a landmark often
    returns to a reading it gave before, a–b–a, which is not a repeat), none equal to its landmark's previous reading;
    then copies of some sightings injected later, before their landmark's next sighting (runs of them: a reading held
    over several images)."""
    n = draw(st.integers(1, 40))
    ids = draw(st.lists(st.integers(0, 3), min_size=n, max_size=n))
    pool = st.tuples(st.sampled_from([1.0, 1.001, 2.5]), st.sampled_from([-0.3, 0.0, 0.281]))
    readings, last = [], {}
    for i in ids:
        value = draw(pool.filter(lambda v, i=i: v != last.get(i)))
        readings.append(value)
        last[i] = value
    # base stamps 1 s apart, some images holding several landmarks (a repeated stamp)
    same = draw(st.lists(st.booleans(), min_size=n, max_size=n))
    times = np.cumsum([0.0 if s and k else 1.0 for k, s in enumerate(same)])
    copies = draw(st.lists(st.integers(0, 3), min_size=n, max_size=n))     # how many times each sighting is held
    rows = []
    for k in range(n):
        rows.append((times[k], k, 0, ids[k], *readings[k]))
        later = [j for j in range(k + 1, n) if ids[j] == ids[k]]
        end = times[later[0]] if later else times[k] + 1.0
        for c in range(copies[k]):   # strictly between this stamp and the landmark's next one
            rows.append((times[k] + (end - times[k]) * (c + 1) / (copies[k] + 2), k, c + 1, ids[k], *readings[k]))
    rows.sort(key=lambda row: (row[0], row[1], row[2]))
    rows = np.array(rows)
    log = RangeBearingLog("injected", ODOMETRY, rows[:, 0], rows[:, 4], rows[:, 5], rows[:, 3].astype(np.int64),
                          TRUTH, np.arange(4), np.zeros((4, 2)), notes=("read",))
    return log, rows[:, 2] > 0, rows


@settings(max_examples=300, deadline=None, derandomize=True)
@given(logs_with_repeats())
def test_exactly_the_injected_repeats_are_dropped_and_nothing_else_moves(case):
    log, injected, rows = case
    kept, found = drop_repeated_readings(log)
    assert np.array_equal(found.dropped, injected)
    assert found.count == int(injected.sum())
    base = ~injected
    for name in ("sighting_times", "ranges", "bearings", "landmark_ids"):
        assert np.array_equal(getattr(kept, name), getattr(log, name)[base])
    for name in ("odometry", "ground_truth", "truth_ids", "truth_positions"):
        assert np.array_equal(getattr(kept, name), getattr(log, name))
    assert kept.notes[:-1] == log.notes and ("none dropped" in kept.notes[-1]) == (not found.count)
    # each repeat's age is its stamp less its first report's (the injected copy's original)
    first_time = {int(k): t for t, k, c in rows[:, :3] if c == 0}
    assert np.allclose(found.ages_s, [t - first_time[int(k)] for t, k, c in rows[injected, :3]])
    assert np.all(found.ages_s >= 0)   # 0: the same row twice in one image (none on MRCLAM)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(logs_with_repeats())
def test_whole_images_drops_the_images_holding_a_repeat_and_nothing_else(case):
    log, injected, _ = case
    kept, found = drop_repeated_readings(log, whole_images=True)
    stale = np.isin(log.sighting_times, log.sighting_times[injected])
    assert np.array_equal(found.repeats, injected)
    assert np.array_equal(found.image_mates, stale & ~injected)
    assert found.images == len(np.unique(log.sighting_times[injected]))
    for name in ("sighting_times", "ranges", "bearings", "landmark_ids"):
        assert np.array_equal(getattr(kept, name), getattr(log, name)[~stale])
    # the repeats themselves are the same as without whole_images
    _, alone = drop_repeated_readings(log)
    assert np.array_equal(alone.repeats, found.repeats) and np.array_equal(alone.ages_s, found.ages_s)
    assert not alone.image_mates.any() and alone.images == 0


@settings(max_examples=200, deadline=None, derandomize=True)
@given(logs_with_repeats(), st.floats(0.0, 1.0))
def test_the_rule_reads_only_earlier_rows(case, fraction):
    """What is dropped in a log's first part does not depend on what comes after (a cut log, `--until`, reads the
    same)."""
    log, _, _ = case
    cut = int(fraction * len(log))
    whole, _ = repeated_readings(log.landmark_ids, log.ranges, log.bearings)
    part, _ = repeated_readings(log.landmark_ids[:cut], log.ranges[:cut], log.bearings[:cut])
    assert np.array_equal(part, whole[:cut])


def test_a_reading_equal_to_an_older_one_with_another_between_is_kept():
    ids = np.array([7, 7, 7, 7, 3, 7])
    ranges = np.array([2.0, 2.0, 2.1, 2.0, 2.0, 2.0])
    bearings = np.array([0.1, 0.1, 0.1, 0.1, 0.1, 0.1])
    repeat, first = repeated_readings(ids, ranges, bearings)
    # 1 holds 0; 2 differs in range; 3 returns to 0's reading after 2's (a new image); 4 is another landmark;
    # 5 holds 3 across landmark 3's sighting
    assert repeat.tolist() == [False, True, False, False, False, True]
    assert first.tolist() == [0, 0, 2, 3, 4, 3]


def test_robot_5s_held_reading_while_turning(mrclam_dir):
    """MRCLAM robot 5 reports landmark 12 (barcode 61) as 3.612 m, +0.281 rad at 13.16, 13.32 and 13.46 s while it
    turns (docs/fastslam-history.md, session 47): the first report is kept at 13.16 s, the other two dropped."""
    log = read_mrclam(mrclam_dir, 5, until=20.0)
    kept, found = drop_repeated_readings(log)
    held = (log.landmark_ids == 12) & (log.ranges == 3.612) & (log.bearings == 0.281)
    assert log.sighting_times[held].tolist() == pytest.approx([13.16, 13.32, 13.46])
    assert found.dropped[held].tolist() == [False, True, True]
    assert found.ages_s[held[found.dropped]].tolist() == pytest.approx([0.16, 0.30])
    assert len(kept) == len(log) - found.count
    # whole images: landmark 14's first report at 13.32 s (as stale as the held reading beside it) goes too, and
    # landmark 13's at 13.46 s; 13.16 s, the held reading's own image, stays whole
    whole, images = drop_repeated_readings(log, whole_images=True)
    at = np.isin(log.sighting_times, [13.32, 13.46])
    assert np.array_equal(images.dropped & (log.sighting_times < 14.0), at & (log.sighting_times < 14.0))
    assert sorted(log.landmark_ids[at & ~found.dropped].tolist()) == [13, 14]
    assert np.sum(whole.sighting_times == 13.16) == np.sum(log.sighting_times == 13.16)


def _inject(folder, every: int) -> int:
    """Copies of every ``every``-th landmark sighting of Robot1_Measurement.dat.gz 0.1 s after it (before the
    synthetic camera's next image, 0.2 s later): held readings. Returns how many."""
    path = folder / "Robot1_Measurement.dat.gz"
    with gzip.open(path, "rt") as stream:
        lines = stream.read().splitlines()
    rows = [line for line in lines if not line.startswith("#")]
    robot_barcode = "5"     # subject 2's sightings (the reader drops them anyway)
    copies = [" ".join([f"{float(line.split()[0]) + 0.1:.10g}", *line.split()[1:]])
              for line in rows[::every] if line.split()[1] != robot_barcode]
    merged = sorted(rows + copies, key=lambda line: float(line.split()[0]))
    with gzip.open(path, "wt") as stream:
        stream.write("\n".join([line for line in lines if line.startswith("#")] + merged) + "\n")
    return len(copies)


@pytest.mark.timeout(1200)
@pytest.mark.parametrize("mode", ["readings", "images"])
def test_slam_dataset_drop_repeats_gives_the_clean_log_s_run(tmp_path, synthetic, mode):
    """A log with held readings injected, run with --drop-repeats, gives the clean log's run figure for figure; the
    count is in --json and the note in the notes; without the option the held readings are sightings (more frames)."""
    clean, held = tmp_path / "clean", tmp_path / "held"
    synthetic.write(clean, seconds=30.0)
    synthetic.write(held, seconds=30.0)
    injected = _inject(held, 7)
    assert injected > 10
    noise = tmp_path / "noise.toml"
    assert run_cli("slam", "noise", "mrclam", str(clean), "--robot", "1", "--out", str(noise), "--window", "2")[0] == 0

    def run(folder, *extra):
        status, out, err = run_cli("slam", "dataset", "mrclam", str(folder), "--robot", "1", "--particles", "5",
                                   "--noise", str(noise), "--out", str(tmp_path / f"{folder.name}{len(extra)}.npz"),
                                   "--json", *extra)
        assert status == 0, err
        return json.loads(out)

    reference, dropped, kept = run(clean), run(held, "--drop-repeats", mode), run(held)
    assert dropped["repeated_readings_dropped"] == injected
    # the injected copies have stamps of their own: no other reading shares their images
    assert dropped.get("repeated_image_mates_dropped", 0) == 0 and ("repeated_image_mates_dropped" in dropped) == \
        (mode == "images")
    assert "repeated_readings_dropped" not in kept and "repeated_readings_dropped" not in reference
    assert sum("word for word" in note for note in dropped["notes"]) == 1
    assert kept["frames"] > reference["frames"]
    volatile = {"out", "notes", "repeated_readings_dropped", "repeated_image_mates_dropped", "dataset"}
    assert {k: v for k, v in dropped.items() if k not in volatile} == \
        {k: v for k, v in reference.items() if k not in volatile}

