"""Readings a camera repeated word for word: one measurement, not two.

A range-bearing camera that hands back its last detection of a landmark when a new image has none (MRCLAM's does:
robot 5 reports landmark 12 as 3.612 m, +0.281 rad at 13.16, 13.32 and 13.46 s while turning) writes the same
reading again under a later stamp. Taken as a new sighting it is counted twice (its error is the first one's, exactly:
covariances shrink as if it were independent) and placed at the later stamp's pose (the image is older than its
stamp: while the robot turns, its bearing is off by the turn since the first report).

The rule (:func:`repeated_readings`): a sighting is a repeat when its range and bearing are equal, exactly, to the
last earlier sighting of the same landmark in the log's order (the camera's held reading). Not "equal to any earlier
reading": a different reading in between means the camera was not holding one, and a still camera that returns to a
value it gave before (a–b–a, 55–175 rows per MRCLAM robot) is a new image. No time limit: the held reading is the
same measurement however late it is reported. Exact equality of the values as read, so only a text log's identical
fields match. A fresh image can match by chance (the same mm and mrad twice); on MRCLAM, between consecutive images
of one landmark, a difference of exactly (0, 0) is 1.7–4× as frequent as each one-unit difference beside it while
the robot moves or turns, and 4.7–9× while it is still: most are held readings. The rule cannot tell a chance match
from a held one; dropping a chance match loses one sighting of a landmark seen hundreds of times.

On MRCLAM (benchmarks/mrclam_repeated_readings.py) 0.7–4.8 % of a robot's sightings are repeats, 0.24–0.48 s old at
the median (up to 11 s). They gather where the robot is still (4–24 % of its sightings there), not while it turns
(0.3–1.0 %, as while it drives straight: 0.6–2.0 %); but there a repeat is off by the turn since its first report.

:func:`drop_repeated_readings` keeps the first report of each run of equal readings, at its own stamp, and drops
the rest, said in the log's notes. The first report's stamp is the nearer one: where the truth turned more than
0.02 rad between a first report and its repeat (14 repeats, robots 1–5), the bearing is nearer the truth at the
first report's stamp in 13. Dropping rather than moving the repeat to its first stamp: the first report is already
there, and a second copy at the same stamp is the same double count.

``whole_images=True`` also drops the other readings of an image that holds a repeat (same stamp). A held reading says
the camera delivered, under that stamp, a result at least as old as the repeat; the image's other readings, though
new, are stamped as late. On MRCLAM robot 5 landmark 14's first report at 13.32 s, beside the held landmark 12, is
−0.073 rad off the truth at its stamp and −0.019 at 13.16 s (the held reading's first report); landmark 13's at
13.46 s −0.106 and −0.022. Dropping only the repeats leaves those readings alone in their images, and ``--frame
checked`` then puts the map's frame on 13.32 s (landmarks within the NEES bound 40 → 33 %, not fitted; 93 → 7 %,
the default model). The cost: 1.7–7.8 % of a robot's sightings instead of 0.7–4.8 %. Off by default
(a caller opts in: ``p3at slam dataset --drop-repeats readings|images``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .landmark_log import RangeBearingLog


@dataclass(frozen=True)
class RepeatedReadings:
    """What :func:`drop_repeated_readings` dropped.

    repeats: (N,) bool over the log's sightings before dropping, the word-for-word repeats; ages_s: (R,) the stamp of
    each repeat less its first report's (how old the image at least is), in the log's order; image_mates: (N,) bool,
    the other readings of the images holding a repeat, dropped with ``whole_images`` (all False otherwise); images:
    how many images those are (0 without ``whole_images``).
    """

    repeats: np.ndarray
    ages_s: np.ndarray
    image_mates: np.ndarray
    images: int = 0

    @property
    def dropped(self) -> np.ndarray:
        """(N,) bool: every sighting dropped."""
        return self.repeats | self.image_mates

    @property
    def count(self) -> int:
        """How many repeats were dropped."""
        return int(self.repeats.sum())

    @property
    def mates_count(self) -> int:
        """How many other readings of their images were dropped with them."""
        return int(self.image_mates.sum())

    def note(self) -> str:
        if not self.count:
            return "no reading repeats its landmark's previous one word for word (drop_repeated_readings): none dropped"
        mates = (f"; with them the {self.mates_count} other readings of the {self.images} images holding one, stamped "
                 "as late" if self.mates_count else "")
        return (f"dropped {self.count} readings that repeat their landmark's previous one word for word (the "
                f"camera's held reading, counted once at its first stamp; {self.count} of "
                f"{len(self.repeats)} sightings, {np.median(self.ages_s):.2f} s old at the median, "
                f"{self.ages_s.max():.2f} s at most){mates}")


def repeated_readings(landmark_ids: np.ndarray, ranges: np.ndarray,
                      bearings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(repeat (N,) bool, first (N,) int): whether each sighting's range and bearing equal, exactly, those of the last
    earlier sighting of its landmark (in the given order), and the index of the first report of its run of equal
    readings (itself when it is not a repeat). The arrays (N,) in the log's order (its stamps non-decreasing), as a
    RangeBearingLog holds them."""
    n = len(landmark_ids)
    repeat = np.zeros(n, bool)
    first = np.arange(n)
    last: dict[int, int] = {}
    rr, bb = np.asarray(ranges, float).tolist(), np.asarray(bearings, float).tolist()
    for k, i in enumerate(np.asarray(landmark_ids).tolist()):
        j = last.get(i)
        if j is not None and rr[j] == rr[k] and bb[j] == bb[k]:
            repeat[k], first[k] = True, first[j]
        last[i] = k
    return repeat, first


def drop_repeated_readings(log: RangeBearingLog, *, whole_images: bool = False
                           ) -> tuple[RangeBearingLog, RepeatedReadings]:
    """The log without its word-for-word repeats (:func:`repeated_readings`), and with ``whole_images`` without the
    other readings of the images (stamps) holding one; said in its notes, and what was dropped. The odometry, the
    truth and every other sighting are as they were."""
    repeat, first = repeated_readings(log.landmark_ids, log.ranges, log.bearings)
    stale = np.unique(log.sighting_times[repeat])
    mates = np.isin(log.sighting_times, stale) & ~repeat if whole_images else np.zeros(len(repeat), bool)
    found = RepeatedReadings(repeat, log.sighting_times[repeat] - log.sighting_times[first[repeat]], mates,
                             images=int(len(stale)) if whole_images else 0)
    kept = log.with_sightings(~found.dropped)
    return replace(kept, notes=(*log.notes, found.note())), found
