"""The fleet's wire format: exact round trips of full snapshots and deltas, restarts, and a decoder that
rejects malformed or hostile bytes with a WireError (never another exception), fuzzed with hypothesis."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from runtime.fleet import mapwire
from runtime.fleet.mapwire import DELTA, FULL, MapEncoder, MapStream, StaleMessage, WireError, decode

SESSION = "0123456789abcdef"


def make_map(n: int, seed: int = 0, robot: str = "robot1", d: int = 8, ids=None) -> LandmarkMap:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, 3, 3))
    return LandmarkMap(rng.normal(size=(n, 3)) * 5, a @ a.transpose(0, 2, 1) + np.eye(3),
                       rng.normal(size=(n, d)).astype(np.float32),
                       np.arange(n) * 3 + 7 if ids is None else ids, rng.integers(1, 9, n), robot, "start",
                       trajectory=np.column_stack([np.arange(4.0), rng.normal(size=(4, 3))]),
                       metadata={"true_start_pose": [1.0, 2.0, 0.5], "note": "x"})


def assert_same_map(a: LandmarkMap, b: LandmarkMap) -> None:
    for name in ("positions", "covariances", "descriptors", "ids", "counts", "seen_by", "trajectory"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.robot, a.frame, a.robots, a.metadata) == (b.robot, b.frame, b.robots, b.metadata)


def evolve(m: LandmarkMap, seed: int) -> LandmarkMap:
    """The next snapshot of a growing map: some landmarks moved, one removed, new ones added, trajectory grown."""
    rng = np.random.default_rng(seed)
    keep = np.ones(len(m), bool)
    if len(m):
        keep[rng.integers(len(m))] = False
    old = m.subset(keep)
    old.positions[:5] += 0.01  # five re-observed landmarks
    old.counts[:5] += 1
    extra = make_map(3, seed + 100, m.robot, m.descriptor_size, ids=np.arange(3) + 10_000 + 10 * seed)
    out = LandmarkMap(np.vstack([old.positions, extra.positions]), np.concatenate([old.covariances, extra.covariances]),
                      np.vstack([old.descriptors, extra.descriptors]), np.concatenate([old.ids, extra.ids]),
                      np.concatenate([old.counts, extra.counts]), m.robot, m.frame,
                      trajectory=np.vstack([m.trajectory, [[len(m.trajectory), 0.0, 0.0, 0.0]]]),
                      metadata=dict(m.metadata))
    return out


def test_full_snapshot_round_trips_exactly():
    m = make_map(20)
    message = decode(mapwire.encode_full("robot1", SESSION, 4, 12.5, m))
    assert (message.kind, message.robot, message.session, message.sequence, message.stamp) == (
        FULL, "robot1", SESSION, 4, 12.5)
    assert_same_map(message.landmark_map, m)


def test_deltas_rebuild_every_snapshot_and_are_smaller_than_full_ones():
    encoder = MapEncoder("robot1", SESSION, full_every=5)
    stream = MapStream("robot1")
    m = make_map(200)
    kinds, sizes = [], []
    for step in range(12):
        kind, data = encoder.encode(m, float(step))
        kinds.append(kind)
        sizes.append(len(data))
        assert_same_map(stream.accept(decode(data)), m)
        assert stream.sequence == step
        m = evolve(m, step)
    assert kinds == [FULL, DELTA, DELTA, DELTA, DELTA, FULL, DELTA, DELTA, DELTA, DELTA, FULL, DELTA]
    assert max(s for s, k in zip(sizes, kinds, strict=True) if k == DELTA) < min(
        s for s, k in zip(sizes, kinds, strict=True) if k == FULL) / 4


def test_a_missed_delta_is_refused_until_a_snapshot_arrives():
    encoder = MapEncoder("robot1", SESSION, full_every=3)
    stream = MapStream("robot1")
    m0 = make_map(10)
    stream.accept(decode(encoder.encode(m0, 0.0)[1]))
    encoder.encode(evolve(m0, 1), 1.0)  # lost on the way
    m2 = evolve(evolve(m0, 1), 2)
    with pytest.raises(WireError, match="needs message 1"):
        stream.accept(decode(encoder.encode(m2, 2.0)[1]))
    assert_same_map(stream.map, m0)  # the last good map is kept
    assert_same_map(stream.accept(decode(encoder.snapshot())), m2)  # the queried snapshot catches up
    m3 = evolve(m2, 3)
    kind, data = encoder.encode(m3, 3.0)
    assert kind == FULL
    stream.accept(decode(data))
    m4 = evolve(m3, 4)
    assert_same_map(stream.accept(decode(encoder.encode(m4, 4.0)[1])), m4)


def test_a_restarted_robot_starts_a_new_session_from_sequence_zero():
    stream = MapStream("robot1")
    first = MapEncoder("robot1")
    for step in range(3):
        stream.accept(decode(first.encode(make_map(5, step), step)[1]))
    second = MapEncoder("robot1")
    assert second.session != first.session
    m = make_map(7, 9)
    assert_same_map(stream.accept(decode(second.encode(m, 0.0)[1])), m)
    assert (stream.sequence, stream.restarts) == (0, 1)
    second.encode(make_map(8, 10), 1.0)
    stream.accept(decode(second.snapshot()))
    with pytest.raises(WireError, match="stale"):  # an older snapshot of the same session is refused
        stream.accept(decode(mapwire.encode_full("robot1", second.session, 0, 0.0, m)))
    assert stream.sequence == 1



def test_a_delta_overtaken_by_a_snapshot_is_stale_not_a_missed_base():
    """A query's reply (the latest full snapshot) handled before deltas still on the way: those deltas are older
    than the map held, refused as stale; a missed base would make the receiver ask for a snapshot it holds."""
    stream = MapStream("robot1")
    encoder = MapEncoder("robot1", full_every=100)
    updates = [encoder.encode(make_map(5 + step, step), float(step))[1] for step in range(4)]
    stream.accept(decode(updates[0]))
    stream.accept(decode(encoder.snapshot()))  # the reply: map 3
    for update in updates[1:]:
        with pytest.raises(StaleMessage):
            stream.accept(decode(update))
    assert stream.sequence == 3
    later = encoder.encode(make_map(9, 4), 4.0)[1]
    assert_same_map(stream.accept(decode(later)), make_map(9, 4))  # the next delta applies on the reply's map

def test_status_round_trips():
    data = mapwire.encode_status("robot2", SESSION, 3, 1.5, pose=[1.0, 2.0, 0.1], landmarks=40,
                                 health={"frames_dropped": 2, "camera": "ok"})
    message = decode(data)
    assert message.status == {"pose": [1.0, 2.0, 0.1], "landmarks": 40,
                              "health": {"frames_dropped": 2, "camera": "ok"}, "has_map": True}
    assert message.sequence == 3


def test_a_status_says_whether_its_sequence_names_a_map():
    """A robot's status before its first map says so (its sequence 0 names nothing a query could return); a
    status without the field (an older sender) names a map; anything but a boolean is refused."""
    assert decode(mapwire.encode_status("robot2", SESSION, 0, 0.5, has_map=False)).status["has_map"] is False
    older = _reframe(mapwire.encode_status("robot2", SESSION, 4, 0.5), lambda h: h.pop("has_map"))
    assert decode(older).status["has_map"] is True
    with pytest.raises(WireError, match="has_map"):
        decode(_reframe(mapwire.encode_status("robot2", SESSION, 4, 0.5), lambda h: h.update(has_map=1)))


def _reframe(data: bytes, edit) -> bytes:
    """The message with its JSON header changed by ``edit(header)`` (arrays unchanged)."""
    header_len = struct.unpack_from("<I", data, 8)[0]
    header = json.loads(data[12:12 + header_len])
    edit(header)
    raw = json.dumps(header).encode()
    return data[:8] + struct.pack("<I", len(raw)) + raw + data[12 + header_len:]


@pytest.mark.parametrize("edit, reason", [
    (lambda h: h.update(robot="robot/*"), "not a robot name"),
    (lambda h: h.update(sequence=-1), "outside"),
    (lambda h: h.update(stamp="soon"), "stamp"),
    (lambda h: h["arrays"][0].__setitem__(2, [1_000_000_000, 3]), "outside"),
    (lambda h: h["arrays"][0].__setitem__(1, "<f4"), "dtype"),
    (lambda h: h["arrays"][1].__setitem__(2, [4, 3, 3]), "other arrays have"),
    (lambda h: h.update(robots=[]), "robots"),
    (lambda h: h.pop("metadata"), "missing"),
])
def test_malformed_headers_are_refused_with_a_reason(edit, reason):
    data = _reframe(mapwire.encode_full("robot1", SESSION, 0, 0.0, make_map(5)), edit)
    with pytest.raises(WireError, match=reason):
        decode(data)


def test_non_finite_numbers_and_bad_framing_are_refused():
    m = make_map(5)
    m.positions[2, 1] = np.nan
    with pytest.raises(WireError, match="non-finite"):
        decode(mapwire.encode_full("robot1", SESSION, 0, 0.0, m))
    good = mapwire.encode_full("robot1", SESSION, 0, 0.0, make_map(5))
    for bad, reason in [(good[:-1], "needs"), (good + b"\0", "follow"), (b"XXXX" + good[4:], "magic"),
                        (good[:4] + bytes([2]) + good[5:], "version"), (good[:5] + bytes([9]) + good[6:], "kind"),
                        (good[:10], "shorter"), (b"", "shorter")]:
        with pytest.raises(WireError, match=reason):
            decode(bad)
    with pytest.raises(WireError, match="limit"):
        decode(good, max_bytes=100)


def test_duplicate_ids_are_refused():
    m = make_map(4, ids=np.array([1, 2, 2, 3]))
    with pytest.raises(WireError, match="duplicate"):
        decode(mapwire.encode_full("robot1", SESSION, 0, 0.0, m))


@given(st.binary(max_size=2048))
def test_the_decoder_never_raises_anything_but_wire_error_on_noise(data):
    try:
        decode(data)
    except WireError:
        pass


@given(st.data())
def test_the_decoder_never_raises_anything_but_wire_error_on_mutated_messages(data):
    encoder = MapEncoder("robot1", SESSION, full_every=2)
    m = make_map(data.draw(st.integers(0, 6)), data.draw(st.integers(0, 100)))
    encoder.encode(m, 0.0)
    raw = bytearray(encoder.encode(evolve(m, 1), 1.0)[1] if data.draw(st.booleans()) else encoder.snapshot())
    for _ in range(data.draw(st.integers(1, 8))):
        position = data.draw(st.integers(0, len(raw) - 1))
        raw[position] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        raw = raw[:data.draw(st.integers(0, len(raw)))]
    stream = MapStream("robot1")
    stream.accept(decode(encoder.snapshot()))
    try:
        stream.accept(decode(bytes(raw)))
    except WireError:
        pass


@given(st.data())
def test_a_header_rewritten_by_an_attacker_is_refused_cleanly(data):
    value = data.draw(st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False)
                                   | st.text(max_size=10), lambda c: st.lists(c, max_size=3)
                                   | st.dictionaries(st.text(max_size=5), c, max_size=3), max_leaves=8))
    key = data.draw(st.sampled_from(["robot", "session", "sequence", "stamp", "frame", "robots", "metadata",
                                     "arrays", "base", "trajectory_from"]))
    encoder = MapEncoder("robot1", SESSION, full_every=5)
    m = make_map(3)
    encoder.encode(m, 0.0)
    raw = encoder.encode(evolve(m, 1), 1.0)[1]
    try:
        stream = MapStream("robot1")
        stream.accept(decode(encoder.snapshot()))
        stream.accept(decode(_reframe(raw, lambda h: h.__setitem__(key, value))))
    except WireError:
        pass


def test_metadata_with_numpy_values_and_non_finite_numbers_travels_as_plain_json():
    m = make_map(3)
    m.metadata = {"pose": np.array([1.0, 2.0, 0.5]), "n": np.int64(4), "limit": float("inf"), "nested": [np.nan, 1]}
    message = decode(mapwire.encode_full("robot1", SESSION, 0, 0.0, m))
    assert message.landmark_map.metadata == {"pose": [1.0, 2.0, 0.5], "n": 4, "limit": None, "nested": [None, 1]}
