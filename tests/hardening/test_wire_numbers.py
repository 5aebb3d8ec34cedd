"""The fleet's map messages (runtime/fleet/mapwire) with integers a float cannot hold, anywhere in the header.

A 400-digit integer as the stamp, a pose, a health figure or in the metadata raised OverflowError (float(),
math.isfinite) and a 4300-digit one ValueError, out of ``decode``, which promises WireError for anything a peer
sends; the fusion node's subscriber would have died on it. Integers of more than MAX_INT_DIGITS digits are now
refused while the header is parsed."""
from __future__ import annotations

import json
import struct

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from runtime.fleet import mapwire
from runtime.fleet.mapwire import MAX_INT_DIGITS, WireError, decode

SESSION = "0123456789abcdef"
_KEYS = ["stamp", "sequence", "frame", "robots", "metadata", "arrays", "landmarks", "pose", "health", "base"]


def _map(n: int = 3) -> LandmarkMap:
    rng = np.random.default_rng(0)
    return LandmarkMap(positions=rng.normal(size=(n, 3)), covariances=np.tile(np.eye(3) * 0.01, (n, 1, 1)),
                       descriptors=rng.normal(size=(n, 8)), ids=np.arange(n), robots=["robot1"],
                       trajectory=np.zeros((2, 4)), metadata={"note": "x"})


def _with_raw_value(message: bytes, key: str, raw_value: str, nested: bool) -> bytes:
    """The message with header[key] (or header[key]['x'] / [raw, 0, 0] when nested) set to the JSON text
    ``raw_value``, written by hand: json.dumps cannot write a 5000-digit integer on every Python."""
    header_len = struct.unpack_from("<I", message, 8)[0]
    header = json.loads(message[12:12 + header_len])
    header[key] = "@@"
    text = json.dumps(header)
    value = ('{"x": %s}' if key in ("metadata", "health") else "[%s, 0, 0]") % raw_value if nested else raw_value
    raw = text.replace('"@@"', value).encode()
    return message[:8] + struct.pack("<I", len(raw)) + raw + message[12 + header_len:]


@given(key=st.sampled_from(_KEYS), digits=st.integers(min_value=1, max_value=6000), negative=st.booleans(),
       nested=st.booleans(), status=st.booleans())
@example(key="stamp", digits=400, negative=False, nested=False, status=True)
@example(key="pose", digits=400, negative=False, nested=True, status=True)
@example(key="health", digits=400, negative=True, nested=True, status=True)
@example(key="sequence", digits=5000, negative=False, nested=False, status=False)
def test_any_integer_anywhere_in_a_header_is_wire_error_or_a_valid_message(key, digits, negative, nested, status):
    if status:
        message = mapwire.encode_status("robot1", SESSION, 1, 2.0, pose=(0.0, 0.0, 0.0), landmarks=3)
    else:
        message = mapwire.encode_full("robot1", SESSION, 1, 2.0, _map())
    raw_value = ("-" if negative else "") + "9" * digits
    try:
        decoded = decode(_with_raw_value(message, key, raw_value, nested))
    except WireError as error:
        assert "\n" not in str(error) and len(str(error)) < 400
        return
    assert digits <= MAX_INT_DIGITS  # a longer one never gets through
    assert np.isfinite(decoded.stamp)


def test_a_huge_stamp_is_refused_in_one_line():
    message = mapwire.encode_status("robot1", SESSION, 1, 2.0)
    try:
        decode(_with_raw_value(message, "stamp", "9" * 400, nested=False))
    except WireError as error:
        assert str(error) == f"header holds an integer of 400 digits (at most {MAX_INT_DIGITS})"
    else:
        raise AssertionError("a 400-digit stamp was accepted")
