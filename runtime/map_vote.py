"""A voted map's record of its vote, ``metadata["vote"]`` (estimation/name_vote.py, :func:`vote_metadata`): the
seeds of the runs voted and, per landmark, how many of them hold it. Written by ``benchmarks.mrclam_seed_vote
--out-maps``; read by ``p3at fuse``, which warns of each map's *contested* landmarks (held by fewer than all the
runs: session 34 found every vote of three that kept a duplicate had exactly one, the duplicate) and carries the
record in ``--json`` (key ``vote``). Maps without the key load and fuse as before.
"""
from __future__ import annotations

import numpy as np

from estimation.name_vote import VOTE_KEY

MAX_SEEDS = 1000          # a vote of more runs than this is not one anybody ran: a hostile or broken file
CONTESTED_SHOWN = 5       # contested landmarks named in the warning line; the rest are counted (all are in --json)


def _whole(value, where: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"metadata {VOTE_KEY}.{where} must be a whole number from {low} to {high}, not {value!r:.40}")
    return value


def read_vote(metadata: dict, landmarks: int) -> dict | None:
    """A map's vote record, ``{"seeds", "runs", "held_by", "contested"}`` (``contested``: the landmark indices held
    by fewer than all ``runs``), for a map of ``landmarks`` landmarks; None if it carries none (a map of one run,
    an older map). ValueError naming the field if the key is there but malformed (one line)."""
    record = metadata.get(VOTE_KEY)
    if record is None:
        return None
    if not isinstance(record, dict):
        raise ValueError(f"metadata {VOTE_KEY} must be a mapping, not {record!r:.80}")
    seeds, held_by = record.get("seeds"), record.get("held_by")
    if not isinstance(seeds, list) or not 1 <= len(seeds) <= MAX_SEEDS:
        raise ValueError(f"metadata {VOTE_KEY}.seeds must be a list of 1 to {MAX_SEEDS} seeds, not {seeds!r:.80}")
    seeds = [_whole(s, f"seeds[{i}]", 0, 2**64 - 1) for i, s in enumerate(seeds)]
    if len(set(seeds)) < len(seeds):
        raise ValueError(f"metadata {VOTE_KEY}.seeds repeats a seed ({seeds!r:.80}): a vote of one run twice")
    if not isinstance(held_by, list) or len(held_by) != landmarks:
        raise ValueError(f"metadata {VOTE_KEY}.held_by must list one count per landmark ({landmarks}), not "
                         f"{held_by!r:.80}")
    runs = len(seeds)
    held_by = [_whole(h, f"held_by[{i}]", 0, runs) for i, h in enumerate(held_by)]
    return {"seeds": seeds, "runs": runs, "held_by": held_by,
            "contested": [i for i, h in enumerate(held_by) if h < runs]}


def contested_text(vote: dict, positions: np.ndarray) -> str | None:
    """'has 1 contested landmark of 16: the runs of its vote (seeds 0,1,2) disagree on landmark 7 at (1.23, -0.45)
    m (0.41 m from landmark 3), held by 2 of 3 runs; ...', or None when every run holds every landmark.
    ``positions`` (L, 3): the map's."""
    contested = vote["contested"]
    if not contested:
        return None
    shown = [f"landmark {i} at ({positions[i][0]:.2f}, {positions[i][1]:.2f}) m{_nearest(positions, i)}, held by "
             f"{vote['held_by'][i]} of {vote['runs']} runs" for i in contested[:CONTESTED_SHOWN]]
    more = len(contested) - len(shown)
    return (f"has {len(contested)} contested landmark{'s' if len(contested) > 1 else ''} of {len(vote['held_by'])}: "
            f"the runs of its vote (seeds {','.join(map(str, vote['seeds']))}) disagree on " + "; ".join(shown)
            + (f"; and {more} more" if more else "")
            + ". Such a landmark may be a duplicate of a landmark near it, or two landmarks under one name; a vote "
              "of more runs decides it")


def _nearest(positions: np.ndarray, i: int) -> str:
    """' (1.18 m from landmark 12)': the map's landmark nearest landmark ``i``, where a duplicate's twin would be."""
    distances = np.linalg.norm(positions - positions[i], axis=1)
    distances[i] = np.inf
    if not np.isfinite(distances).any():
        return ""
    j = int(np.argmin(distances))
    return f" ({distances[j]:.2f} m from landmark {j})"
