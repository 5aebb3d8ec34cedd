"""Map files whose metadata the fusion reads, with hostile values (session 23): the keys added since session 14
(``external_ids``, ``identity_conflicts``, the self-check's alarms) give a one-line error naming file and key, or
a map the fusion uses without raising; never an internal error (exit 70)."""
from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from estimation.errors import MapFileError
from estimation.geometry import inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion.fingerprint import map_fingerprint
from fusion.ransac import landmark_identities
from fusion.split import later_gaps, split_id

from .memory import read_bounded

N = 40


def run_cli(*argv) -> tuple[int, str, str]:
    """``p3at ARGV...`` in this process: (exit status, stdout, stderr)."""
    from runtime.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(list(argv))
    return status, out.getvalue(), err.getvalue()


def _pair() -> tuple[LandmarkMap, LandmarkMap]:
    """Two maps of one set of landmarks, the second's frame turned 0.4 rad and shifted: they fuse."""
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-8, 8, (N, 2)), rng.uniform(0, 2, N)])
    descriptors = rng.normal(size=(N, 16)).astype(np.float32)
    cov = np.tile(np.eye(3) * 1e-4, (N, 1, 1))
    m1 = LandmarkMap(points + rng.normal(0, 0.005, (N, 3)), cov, descriptors, robot="robot1")
    local = transform_points(inverse(np.array([1.0, -2.0, 0.4])), points)
    m2 = LandmarkMap(local + rng.normal(0, 0.005, (N, 3)), cov, descriptors, robot="robot2")
    return m1, m2


def _with_metadata(path: Path, landmark_map: LandmarkMap, key: str, value) -> Path:
    """``landmark_map`` saved to ``path`` with ``metadata[key] = value`` written as raw JSON (any value at all)."""
    landmark_map.save(path)
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(bytes(arrays["meta"]).decode())
    meta["metadata"][key] = value
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez_compressed(path, **arrays)
    return path


CONFLICT = {"robot": "robot9", "identity": 3, "kept_row": 0, "distance_m": 1.0, "mahalanobis_d2": 50.0,
            "gate_d2": 16.27}


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("pair")
    m1, m2 = _pair()
    m1.save(folder / "robot1.npz")
    m2.save(folder / "robot2.npz")
    status, _, err = run_cli("fuse", str(folder / "robot1.npz"), str(folder / "robot2.npz"), "--out",
                             str(folder / "fused.npz"))
    assert status == 0, err   # the maps of these tests fuse when nothing is hostile
    return folder / "robot1.npz", folder / "robot2.npz"


@pytest.mark.parametrize("key, value, field", [
    ("external_ids", ["a"] * N, "meta.metadata.external_ids[0]"),              # was ValueError, exit 70
    ("external_ids", [10 ** 30] * N, "meta.metadata.external_ids[0]"),         # OverflowError, exit 70
    ("external_ids", {"a": 1}, "meta.metadata.external_ids"),                   # TypeError, exit 70
    ("external_ids", [[1, 2], [3]], "meta.metadata.external_ids[0]"),          # inhomogeneous array, exit 70
    ("external_ids", [1.5] * N, "meta.metadata.external_ids[0]"),              # read as identity 1 for all
    ("identity_conflicts", 5, "meta.metadata.identity_conflicts"),              # TypeError, exit 70
    ("identity_conflicts", [1, 2], "meta.metadata.identity_conflicts[0]"),      # TypeError, exit 70
    ("identity_conflicts", [{"robot": "x"}], "meta.metadata.identity_conflicts[0].identity"),  # KeyError, exit 70
    ("identity_conflicts", [dict(CONFLICT, distance_m="far")], "meta.metadata.identity_conflicts[0].distance_m"),
])
def test_a_corrupt_identity_field_is_one_line_naming_file_and_key(pair, tmp_path, key, value, field) -> None:
    robot1, robot2 = pair
    hostile = _with_metadata(tmp_path / "hostile.npz", LandmarkMap.load(robot1), key, value)
    for maps in ((robot2, hostile), (hostile, robot2)):   # the first map's metadata is the merged map's
        status, _, err = run_cli("fuse", *map(str, maps), "--out", str(tmp_path / "out.npz"))
        assert status == 2, err
        assert err.count("\n") == 1 and str(hostile) in err and f"'{field}'" in err, err
    assert not (tmp_path / "out.npz").exists()


def test_sound_identity_fields_still_load_and_fuse(pair, tmp_path) -> None:
    robot1, robot2 = pair
    m = LandmarkMap.load(robot1)
    m.metadata["external_ids"] = list(range(N - 1)) + [-1]
    m.metadata["identity_conflicts"] = [CONFLICT]
    m.save(tmp_path / "ids.npz")
    back = LandmarkMap.load(tmp_path / "ids.npz")
    assert back.metadata["external_ids"] == m.metadata["external_ids"]
    assert back.metadata["identity_conflicts"] == [CONFLICT]
    status, _, err = run_cli("fuse", str(tmp_path / "ids.npz"), str(robot2), "--out", str(tmp_path / "out.npz"))
    assert status == 0 and "robot9 places landmark identity 3" in err, err
    assert LandmarkMap.load(tmp_path / "out.npz").metadata["identity_conflicts"][0] == CONFLICT


def test_many_inherited_conflicts_are_counted_not_printed_one_by_one(pair, tmp_path) -> None:
    robot1, robot2 = pair
    hostile = _with_metadata(tmp_path / "many.npz", LandmarkMap.load(robot1), "identity_conflicts", [CONFLICT] * 5000)
    status, _, err = run_cli("fuse", str(hostile), str(robot2), "--out", str(tmp_path / "out.npz"))
    assert status == 0, err
    assert "5000 landmark identities" in err and err.count("\n") <= 25, err[:500]
    assert len(LandmarkMap.load(tmp_path / "out.npz").metadata["identity_conflicts"]) == 5000   # nothing lost


def test_a_later_alarm_with_a_corrupt_gap_is_not_counted(pair, tmp_path) -> None:
    """A lost map's later alarm naming a list as its gap: TypeError (unhashable) in later_gaps, exit 70."""
    robot1, robot2 = pair
    verdict = {"lost": True, "alarms": [{"first_id_after_gap": N // 2, "t": 3.0}, {"first_id_after_gap": [1]},
                                        {"first_id_after_gap": N // 2 + 3}, "x"]}
    hostile = _with_metadata(tmp_path / "lost.npz", LandmarkMap.load(robot2), "self_check", verdict)
    m = LandmarkMap.load(hostile)
    assert split_id(m) == N // 2 and later_gaps(m) == 1
    status, _, err = run_cli("fuse", str(robot1), str(hostile), "--out", str(tmp_path / "out.npz"))
    assert status in (0, 1) and "internal error" not in err, err


@pytest.mark.parametrize("verdict", ["x", 5, [], {"lost": False, "alarms": 7}, {"lost": True, "alarms": "abc"},
                                     {"lost": True, "alarms": [5]}, {"lost": True}])
def test_later_gaps_of_a_malformed_verdict_is_zero(tmp_path, verdict) -> None:
    m, _ = _pair()
    m.metadata["self_check"] = verdict
    assert later_gaps(m) == 0


json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-(10 ** 40), 10 ** 40), st.floats(allow_nan=False),
                      st.text(max_size=5))
json_value = st.recursive(json_leaf, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                            st.dictionaries(st.text(max_size=4), inner, max_size=4)),
                          max_leaves=12)


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=st.sampled_from(["external_ids", "identity_conflicts"]),
       value=st.one_of(json_value, st.lists(json_leaf, min_size=N, max_size=N),
                       st.lists(st.fixed_dictionaries({k: json_leaf for k in CONFLICT}), max_size=3)))
@example(key="external_ids", value=["a"] * N)
@example(key="external_ids", value=[10 ** 30] * N)
@example(key="external_ids", value=[[1, 2], [3]])
@example(key="external_ids", value={"a": 1})
def test_fuzz_identity_fields(tmp_path, key, value) -> None:
    """Any JSON value under the identity keys: a MapFileError, or a map whose identities and fingerprint (what the
    alignment reads) come without an exception."""
    m, _ = _pair()
    path = _with_metadata(tmp_path / "fuzz.npz", m, key, value)
    loaded = read_bounded(lambda: LandmarkMap.load(path), MapFileError)
    if loaded is None:
        return
    map_fingerprint(loaded)
    ids = landmark_identities(loaded)
    assert ids is None or (ids.dtype == np.int64 and ids.shape == (N,))
    for conflict in loaded.metadata.get("identity_conflicts", []):   # what p3at fuse prints of each
        assert f"{conflict['robot']} {conflict['identity']} {conflict['distance_m']:.2f} {conflict['gate_d2']:.1f}"
