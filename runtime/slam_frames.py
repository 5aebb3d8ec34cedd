"""The camera-frame counts a robot's map carries, ``metadata["slam_frames"]``: how many frames the onboard runtime
received and what became of them. Written with every map the runtime saves or publishes; read by ``p3at fuse`` to
tell a map of the whole route from one built on a fraction of its frames (a starved run: a SLAM stage that fell
behind the camera, or odometry that did not arrive). Maps written before the key existed load without it.
"""
from __future__ import annotations

KEY = "slam_frames"
FIELDS = ("received", "processed", "dropped", "without_odometry")
# more than this fraction of the received frames dropped or without odometry: the map saw only part of its run
STARVED_FRACTION = 0.5


def frame_counts(stats) -> dict[str, int]:
    """The counts from an onboard runtime's ``OnboardStats`` (frames_received, frames_processed, dropped_frames,
    frames_without_odometry)."""
    return {"received": int(stats.frames_received), "processed": int(stats.frames_processed),
            "dropped": int(stats.dropped_frames), "without_odometry": int(stats.frames_without_odometry)}


def read_frame_counts(metadata: dict) -> dict[str, int] | None:
    """A map's frame counts; None if it carries none (an older map, a merged one, a data set's).
    ValueError naming what is wrong if the key is there but is not four whole counts >= 0."""
    counts = metadata.get(KEY)
    if counts is None:
        return None
    # reprs are cut: one line whatever the file holds
    if not isinstance(counts, dict) or sorted(counts) != sorted(FIELDS):
        raise ValueError(f"metadata {KEY} must hold exactly {', '.join(FIELDS)}, not {counts!r:.80}")
    for name in FIELDS:
        value = counts[name]
        # below 2^63 (a frame count, as int64 holds it): a count of 400 digits made starved() raise OverflowError
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1 << 63:
            raise ValueError(f"metadata {KEY}.{name} must be a whole number >= 0 below 2^63, not {value!r:.40}")
    return {name: counts[name] for name in FIELDS}


def starved(counts: dict[str, int]) -> str | None:
    """Why a run counts as starved (more than STARVED_FRACTION of its received frames dropped by a SLAM stage
    that was behind, or without odometry to place them), or None."""
    received = counts["received"]
    lost = counts["dropped"] + counts["without_odometry"]
    if received == 0 or lost <= STARVED_FRACTION * received:
        return None
    return (f"{lost} of its {received} frames ({100 * lost / received:.0f} %) were not mapped: {counts['dropped']} "
            f"dropped (the SLAM stage was behind), {counts['without_odometry']} without odometry")
