"""Landmark data sets as a first-class input: readers that map a data set onto a :class:`RangeBearingLog`.

Readers only read and validate (bounded memory, one-line errors naming file, line and field); playing a log
through FastSLAM is :mod:`estimation.dataset_slam`'s job, so the readers never import the filter.

    from estimation.datasets import read_mrclam
    log = read_mrclam("../shared/data/mrclam/MRCLAM_Dataset2", robot=3)   # .dat or .dat.gz
    log.notes            # what was dropped, verified or corrected (Barcodes.dat is checked against the truth)
    log.stamp_resolution # streams whose stamps were written coarser than their rows (MRCLAM: 0.1 s from 1000 s)
"""
from __future__ import annotations

from .errors import DatasetError
from .landmark_log import RangeBearingLog, integrate_velocities
from .mrclam import (
    BARCODE_POLICIES,
    TRUTH_HEADINGS,
    BarcodeCheck,
    BarcodeVerdict,
    check_barcodes,
    mrclam_robots,
    read_barcodes,
    read_landmark_truth,
    read_mrclam,
)
from .repeats import RepeatedReadings, drop_repeated_readings, repeated_readings
from .stamps import StampQuantization, stamp_quantization
from .tables import find_table, read_table
from .truth_heading import TravelHeadingOffset, align_truth_heading, travel_heading_offset

__all__ = [
    "BARCODE_POLICIES", "BarcodeCheck", "BarcodeVerdict", "DatasetError", "RangeBearingLog", "check_barcodes",
    "find_table", "integrate_velocities", "mrclam_robots", "read_barcodes", "read_landmark_truth", "read_mrclam",
    "read_table", "StampQuantization", "stamp_quantization", "TRUTH_HEADINGS", "TravelHeadingOffset",
    "align_truth_heading", "travel_heading_offset", "RepeatedReadings", "drop_repeated_readings", "repeated_readings",
]
