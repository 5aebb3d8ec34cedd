"""PLY export: a standard PLY header and one vertex per landmark with colour, robot and covariance."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from estimation.ply import COMMON_COLOUR, ROBOT_COLOURS, VERTEX_DTYPE

_NUMPY_OF = {"double": "<f8", "float": "<f4", "uchar": "u1", "uint": "<u4", "int": "<i4"}


def parse_ply(data: bytes) -> tuple[list[str], np.ndarray]:
    """A minimal, independent PLY reader: header lines and the vertex element as a structured array."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[0] == "ply"
    fmt = header[1].split()[1]
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    props = [line.split()[1:] for line in header if line.startswith("property")]
    dtype = np.dtype([(name, _NUMPY_OF[kind]) for kind, name in props])
    body = data[end:]
    if fmt == "binary_little_endian":
        assert len(body) == count * dtype.itemsize
        return header, np.frombuffer(body, dtype)
    assert fmt == "ascii"
    rows = body.decode("ascii").splitlines()
    assert len(rows) == count
    out = np.zeros(count, dtype)
    for i, row in enumerate(rows):
        out[i] = tuple(float(v) if dtype[k].kind == "f" else int(v) for k, v in enumerate(row.split()))
    return header, out


def _map(n: int, robots: int, rng: np.random.Generator) -> LandmarkMap:
    a = rng.normal(size=(n, 3, 3))
    seen = rng.random((n, robots)) < 0.6
    seen[~seen.any(axis=1), 0] = True
    return LandmarkMap(rng.normal(scale=5, size=(n, 3)), a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(3),
                       rng.normal(size=(n, 8)).astype(np.float32), rng.permutation(n * 3)[:n],
                       rng.integers(1, 50, n), robot="fused", robots=[f"robot{i + 1}" for i in range(robots)],
                       seen_by=seen)


@settings(max_examples=25)
@given(n=st.integers(0, 30), robots=st.integers(1, 10), seed=st.integers(0, 2**32 - 1), binary=st.booleans())
def test_ply_holds_position_colour_robot_and_covariance_of_every_landmark(tmp_path_factory, n, robots, seed, binary):
    m = _map(n, robots, np.random.default_rng(seed))
    path = tmp_path_factory.mktemp("ply") / "map.ply"
    m.export_ply(path, binary=binary)
    header, v = parse_ply(path.read_bytes())
    assert [line.split()[2] for line in header if line.startswith("property")] == list(VERTEX_DTYPE.names)
    assert [line.split(maxsplit=3)[3] for line in header if line.startswith("comment robot")] == m.robots
    assert len(v) == n
    np.testing.assert_array_equal(np.column_stack([v["x"], v["y"], v["z"]]), m.positions)  # exact, both formats
    for name, i, j in (("xx", 0, 0), ("xy", 0, 1), ("xz", 0, 2), ("yy", 1, 1), ("yz", 1, 2), ("zz", 2, 2)):
        np.testing.assert_array_equal(v[f"cov_{name}"], m.covariances[:, i, j])
    np.testing.assert_array_equal(v["id"], m.ids)
    np.testing.assert_array_equal(v["count"], m.counts)
    for k in range(n):
        observers = np.flatnonzero(m.seen_by[k])
        assert v["robot"][k] == observers[0]
        assert v["seen_by"][k] == sum(1 << int(r) for r in observers)
        colour = COMMON_COLOUR if len(observers) > 1 else ROBOT_COLOURS[observers[0] % len(ROBOT_COLOURS)]
        assert (v["red"][k], v["green"][k], v["blue"][k]) == tuple(colour)


def test_ply_refuses_more_robots_than_its_bitmask_holds(tmp_path):
    m = _map(3, 33, np.random.default_rng(0))
    with pytest.raises(ValueError, match="33"):
        m.export_ply(tmp_path / "m.ply")
    assert not (tmp_path / "m.ply").exists()
