"""Reader for the UTIAS MRCLAM data sets (Leung et al., IJRR 2011): one robot's log as a RangeBearingLog.

A data set folder holds, as plain ``.dat`` or gzip-compressed ``.dat.gz`` text (``#`` comment lines):

    Robot{n}_Odometry.dat      time v w               s, m/s, rad/s (50 Hz)
    Robot{n}_Measurement.dat   time barcode range bearing   s, -, m, rad (camera)
    Robot{n}_Groundtruth.dat   time x y theta         s, m, m, rad (Vicon)
    Landmark_Groundtruth.dat   subject x y sd_x sd_y  -, m, m, m, m
    Barcodes.dat               subject barcode        subjects 1-5 are the robots, 6-20 the landmarks

Robot{n}_Groundtruth and Landmark_Groundtruth are optional: a lab's own log in this format usually has no motion
capture. Without them the log has no ground truth (``has_ground_truth`` False, no ``truth_ids``; said so in the
notes): it can be mapped, not scored, and Barcodes.dat cannot be checked, so only ``barcodes="table"`` reads it.

Stamps are used as written; a stream whose stamps sit on a grid coarser than its rows (this copy's files have
five significant digits: 0.1 s stamps from t = 1000 s) is reported in the notes and ``stamp_resolution``
(:mod:`.stamps`).

A sighting's barcode names a *subject* through Barcodes.dat. Sightings of robots (subjects 1-5) are not
landmarks and are dropped, as are barcodes the table does not know (misreads); the log's notes count both.

Barcodes.dat is checked against the ground truth before it is used (copies of this data set are known to carry
swapped entries): every sighting, placed in the world from the robot's true pose, should fall near its
subject's true position. :func:`check_barcodes` measures, for each barcode, the median distance to every
landmark and reports the barcodes whose table subject is not the one their sightings fall on. ``barcodes``
chooses what the reader does with it: ``"verified"`` (default) refuses a table that disagrees, naming the
entries; ``"inferred"`` uses the subjects the sightings fall on and says so in the notes; ``"table"`` trusts
the file and notes that it did.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DatasetError
from .landmark_log import RangeBearingLog, integrate_velocities
from .stamps import quantization_note, spread_rows, stamp_quantization
from .tables import find_table, read_table
from .truth_heading import align_truth_heading

ROBOT_SUBJECTS = range(1, 6)          # subjects 1-5 are the robots; landmarks are the others
BARCODE_POLICIES = ("verified", "inferred", "table")
TRUTH_HEADINGS = ("mocap", "travel")   # the ground truth's heading as written, or turned onto the direction of travel
MIN_SIGHTINGS_TO_CHECK = 10           # fewer sightings of a barcode cannot tell its landmark apart
CLEAR_MARGIN_M = 0.3                  # a better subject must be nearer by this much (and by half) to count


@dataclass(frozen=True)
class BarcodeVerdict:
    """What the sightings of one barcode say about its table entry.

    table_subject: the subject Barcodes.dat gives; best_subject: the landmark the sightings fall on;
    table_median_m / best_median_m: median distance of the sightings (placed from the true pose) to each.
    """

    barcode: int
    table_subject: int
    best_subject: int
    table_median_m: float
    best_median_m: float
    sightings: int

    @property
    def disagrees(self) -> bool:
        return (self.best_subject != self.table_subject and self.table_median_m > 2.0 * self.best_median_m
                and self.table_median_m - self.best_median_m > CLEAR_MARGIN_M)

    def __str__(self) -> str:
        return (f"barcode {self.barcode}: table says subject {self.table_subject} ({self.table_median_m:.2f} m "
                f"median), its {self.sightings} sightings fall on subject {self.best_subject} "
                f"({self.best_median_m:.2f} m)")


@dataclass(frozen=True)
class BarcodeCheck:
    """The verdicts of every landmark barcode one robot saw often enough, and those it could not check."""

    verdicts: tuple[BarcodeVerdict, ...]
    unchecked: tuple[int, ...]

    @property
    def disagreements(self) -> tuple[BarcodeVerdict, ...]:
        return tuple(v for v in self.verdicts if v.disagrees)

    def inferred(self, table: dict[int, int]) -> dict[int, int]:
        """The barcode -> subject table with each disagreeing entry replaced by the subject its sightings fall on."""
        mapping = dict(table)
        for verdict in self.disagreements:
            mapping[verdict.barcode] = verdict.best_subject
        landmarks = [s for s in mapping.values() if s not in ROBOT_SUBJECTS]
        if len(set(landmarks)) != len(landmarks):
            raise DatasetError("the barcodes' sightings do not give a one-to-one barcode -> landmark table: "
                               + "; ".join(str(v) for v in self.disagreements))
        return mapping


def mrclam_robots(folder: str | Path) -> list[int]:
    """The robot numbers with an odometry file in ``folder``."""
    folder = Path(folder)
    found = {int(p.name[5:p.name.index("_")]) for p in folder.glob("Robot*_Odometry.dat*")
             if p.name[5:p.name.index("_")].isdigit()}
    return sorted(found)


def read_barcodes(folder: str | Path) -> dict[int, int]:
    """Barcodes.dat as barcode -> subject (a DatasetError if a barcode or a subject appears twice)."""
    path = find_table(Path(folder), "Barcodes")
    rows, lines = read_table(path, ("subject", "barcode"), integer_columns=("subject", "barcode"), max_rows=10_000)
    mapping: dict[int, int] = {}
    subjects: set[int] = set()
    for (subject, barcode), line in zip(rows.astype(np.int64), lines, strict=True):
        if barcode in mapping or subject in subjects:
            raise DatasetError(f"{path}:{line}: subject {subject} or barcode {barcode} appears twice")
        mapping[int(barcode)] = int(subject)
        subjects.add(int(subject))
    if not mapping:
        raise DatasetError(f"{path}: no entries")
    return mapping


def read_landmark_truth(folder: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Landmark_Groundtruth.dat as (subjects (L,) int64, positions (L, 2) m)."""
    path = find_table(Path(folder), "Landmark_Groundtruth")
    rows, lines = read_table(path, ("subject", "x", "y", "sd_x", "sd_y"), integer_columns=("subject",),
                             max_rows=100_000)
    if not len(rows):   # (a FIFO reads as empty) no landmark to score against: every sighting was quietly unknown
        raise DatasetError(f"{path}: no entries")
    subjects = rows[:, 0].astype(np.int64)
    if len(np.unique(subjects)) != len(subjects):
        raise DatasetError(f"{path}: a landmark subject appears twice")
    if np.any(rows[:, 3:] < 0):
        raise DatasetError(f"{path}:{int(lines[np.flatnonzero(np.any(rows[:, 3:] < 0, axis=1))[0]])}: "
                           "field sd_x or sd_y is negative")
    return subjects, rows[:, 1:3].copy()


def check_barcodes(table: dict[int, int], subjects: np.ndarray, positions: np.ndarray, true_poses: np.ndarray,
                   barcodes: np.ndarray, ranges: np.ndarray, bearings: np.ndarray) -> BarcodeCheck:
    """Compare each landmark barcode's table subject with the landmark its sightings fall on.

    true_poses (N, 3): the robot's true pose at each sighting; barcodes, ranges, bearings (N,).
    """
    x = true_poses[:, 0] + ranges * np.cos(true_poses[:, 2] + bearings)
    y = true_poses[:, 1] + ranges * np.sin(true_poses[:, 2] + bearings)
    verdicts, unchecked = [], []
    for code in np.unique(barcodes):
        subject = table.get(int(code))
        if subject is None or subject in ROBOT_SUBJECTS or subject not in set(subjects.tolist()):
            continue
        seen = barcodes == code
        if seen.sum() < MIN_SIGHTINGS_TO_CHECK:
            unchecked.append(int(code))
            continue
        distance = np.hypot(x[seen, None] - positions[None, :, 0], y[seen, None] - positions[None, :, 1])
        medians = np.median(distance, axis=0)                      # (L,)
        best = int(np.argmin(medians))
        mine = int(np.flatnonzero(subjects == subject)[0])
        verdicts.append(BarcodeVerdict(int(code), int(subject), int(subjects[best]), float(medians[mine]),
                                       float(medians[best]), int(seen.sum())))
    return BarcodeCheck(tuple(verdicts), tuple(unchecked))


SPREADABLE = ("odometry", "ground truth")
# magnitudes a robot table's fields may have: stamps up to 1e10 s (MRCLAM's are Unix times, 1.25e9 s), every other
# field (m, rad, m/s, rad/s, barcodes) up to 1e6. A stamp of 1e300 overflowed the odometry's integration and the
# stamp grids (RuntimeWarnings on stderr, then inf poses), silently when it was the last row.
MAX_TIME_S = 1e10
MAX_FIELD = 1e6


def read_mrclam(folder: str | Path, robot: int, *, barcodes: str = "verified",
                until: float | None = None, spread: tuple[str, ...] = (), truth_heading: str = "mocap"
                ) -> RangeBearingLog:
    """Robot ``robot``'s log from an MRCLAM data set folder (see the module docstring for ``barcodes``).

    ``truth_heading``: "mocap" keeps Vicon's heading as written; "travel" turns it onto the robot's direction of
    travel (:mod:`.truth_heading`: Vicon's marker frame is 0.003–0.017 rad off the wheels' axis on this data set, and
    robot 1's wanders), said in the notes. A log without ground truth reads the same either way.

    ``until`` (s): read only the log's first part, up to that time (a fast test, a quick look).
    ``spread``: streams among SPREADABLE whose rows sharing a coarse stamp are placed evenly about it
    (:func:`.stamps.spread_rows`; a measurement's opt-in, off by default; noted when used).
    """
    folder = Path(folder)
    if barcodes not in BARCODE_POLICIES:
        raise ValueError(f"barcodes must be one of {', '.join(BARCODE_POLICIES)}, not {barcodes!r}")
    if truth_heading not in TRUTH_HEADINGS:
        raise ValueError(f"truth_heading must be one of {', '.join(TRUTH_HEADINGS)}, not {truth_heading!r}")
    if not set(spread) <= set(SPREADABLE):
        raise ValueError(f"spread takes streams among {', '.join(SPREADABLE)}, not {spread!r}")
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder")
    if robot < 1:
        raise DatasetError(f"robot must be a positive number, not {robot}")
    bound = {"until": until}
    table = read_barcodes(folder)
    prefix = f"Robot{robot}_"
    absent = [stem for stem in ("Landmark_Groundtruth", prefix + "Groundtruth") if not _is_there(folder, stem)]
    subjects, positions = read_landmark_truth(folder) if "Landmark_Groundtruth" not in absent \
        else (np.zeros(0, np.int64), np.zeros((0, 2)))
    odometry, _ = _read_robot_table(folder, prefix + "Odometry", ("time", "v", "w"), bound)
    sightings, _ = _read_robot_table(folder, prefix + "Measurement", ("time", "barcode", "range", "bearing"), bound,
                                     integer_columns=("barcode",))
    truth = _read_robot_table(folder, prefix + "Groundtruth", ("time", "x", "y", "theta"), bound)[0] \
        if prefix + "Groundtruth" not in absent else np.zeros((0, 4))
    name = f"{folder.name}/Robot{robot}"
    if len(odometry) < 2:
        raise DatasetError(f"{folder}/{prefix}Odometry: fewer than 2 rows")
    notes: list[str] = []
    if prefix + "Groundtruth" in absent:
        notes.append(f"no ground truth ({prefix}Groundtruth.dat absent): the log can be mapped, not scored")
    elif len(truth) < 2:
        notes.append(f"no ground truth ({prefix}Groundtruth.dat holds {len(truth)} rows): the log can be mapped, not "
                     "scored")
    elif absent:
        notes.append("no landmark ground truth (Landmark_Groundtruth.dat absent): the map's landmarks are not scored")

    codes = sightings[:, 1].astype(np.int64)
    if barcodes == "table":
        notes.append("Barcodes.dat used as it is, not checked against the ground truth (barcodes='table')")
    else:
        if len(truth) < 2 or not len(subjects):
            missing = f" ({' and '.join(f'{stem}.dat' for stem in absent)} absent)" if absent else ""
            raise DatasetError(f"{name}: Barcodes.dat cannot be verified without ground truth{missing}; "
                               "pass barcodes='table' (p3at: --barcodes table) to trust it")
        probe = RangeBearingLog(name, _odometry_rows(odometry), np.zeros(0), np.zeros(0), np.zeros(0),
                                np.zeros(0, np.int64), truth)
        check = check_barcodes(table, subjects, positions, probe.true_pose(sightings[:, 0]), codes,
                               sightings[:, 2], sightings[:, 3])
        wrong = check.disagreements
        if wrong and barcodes == "verified":
            raise DatasetError(f"{folder}: Barcodes.dat disagrees with the ground truth (swapped entries?): "
                               + "; ".join(str(v) for v in wrong)
                               + ". Pass barcodes='inferred' to use the subjects the sightings fall on")
        if wrong:
            table = check.inferred(table)
            notes.append("Barcodes.dat corrected from the ground truth: " + "; ".join(str(v) for v in wrong))
        else:
            notes.append(f"Barcodes.dat verified against the ground truth ({len(check.verdicts)} barcodes)")
        if check.unchecked:
            notes.append(f"barcodes seen too rarely to verify (< {MIN_SIGHTINGS_TO_CHECK} sightings): "
                         + ", ".join(map(str, check.unchecked)))

    subject_of = np.array([table.get(int(c), -1) for c in codes], np.int64)
    is_robot = np.isin(subject_of, list(ROBOT_SUBJECTS))
    unknown = subject_of < 0
    if is_robot.any():
        notes.append(f"dropped {int(is_robot.sum())} sightings of other robots (subjects "
                     + ", ".join(map(str, sorted(set(subject_of[is_robot].tolist())))) + ")")
    if unknown.any():
        notes.append(f"dropped {int(unknown.sum())} sightings of barcodes not in Barcodes.dat ("
                     + ", ".join(map(str, sorted(set(codes[unknown].tolist())))) + ")")
    keep = ~(is_robot | unknown)
    quantized = tuple(q for q in (stamp_quantization(odometry[:, 0], "odometry"),
                                  stamp_quantization(sightings[:, 0], "sightings"),
                                  stamp_quantization(truth[:, 0], "ground truth")) if q is not None)
    if quantized:
        notes.append(quantization_note(quantized))
    for q in quantized:
        if q.stream in spread:
            stream_rows = odometry if q.stream == "odometry" else truth
            stream_rows[:, 0] = spread_rows(stream_rows[:, 0], q)
            notes.append(f"{q.stream} rows sharing a {q.resolution_s:g} s stamp spread evenly about it (spread=)")
    log = RangeBearingLog(
        name=name, odometry=_odometry_rows(odometry), sighting_times=sightings[keep, 0],
        ranges=sightings[keep, 2], bearings=sightings[keep, 3], landmark_ids=subject_of[keep],
        ground_truth=truth, truth_ids=subjects, truth_positions=positions, notes=tuple(notes),
        stamp_resolution=quantized, velocities=odometry)
    if truth_heading == "travel" and log.has_ground_truth:
        log = align_truth_heading(log)[0]
    return log


def _is_there(folder: Path, stem: str) -> bool:
    """Whether ``stem.dat`` or ``stem.dat.gz`` is in ``folder`` in any form (a broken one is read_table's error)."""
    return any((folder / name).is_symlink() or (folder / name).exists() for name in (f"{stem}.dat", f"{stem}.dat.gz"))


def _read_robot_table(folder: Path, stem: str, columns, bound, integer_columns=()) -> tuple[np.ndarray, np.ndarray]:
    path = find_table(folder, stem)
    rows, lines = read_table(path, columns, integer_columns=integer_columns, **bound)
    for k, name in enumerate(columns):
        limit = MAX_TIME_S if name == "time" else MAX_FIELD
        far = np.flatnonzero(np.abs(rows[:, k]) > limit)
        if len(far):
            raise DatasetError(f"{path}:{int(lines[far[0]])}: field {name} is out of range ({rows[far[0], k]:.3g}; "
                               f"at most {limit:g} in magnitude)")
    back = np.flatnonzero(np.diff(rows[:, 0]) < 0)
    if len(back):
        raise DatasetError(f"{path}:{int(lines[back[0] + 1])}: field time goes backwards "
                           f"({float(rows[back[0] + 1, 0])} after {float(rows[back[0], 0])})")
    if "range" in columns and np.any(rows[:, columns.index("range")] < 0):
        bad = int(np.flatnonzero(rows[:, columns.index("range")] < 0)[0])
        raise DatasetError(f"{path}:{int(lines[bad])}: field range is negative")
    return rows, lines


def _odometry_rows(odometry: np.ndarray) -> np.ndarray:
    return integrate_velocities(odometry[:, 0], odometry[:, 1], odometry[:, 2])
