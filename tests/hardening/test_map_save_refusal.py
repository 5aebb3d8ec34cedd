"""A map that ``LandmarkMap.save`` writes is a map ``LandmarkMap.load`` reads (session 46, H). The writer refused only
names and typed metadata its reader refuses; a map built in memory with a NaN (a diverged filter, a degenerate
triangulation), a covariance that is not positive definite, duplicate ids or arrays of the wrong shape was written,
and the robot's map file was then unreadable: the map lost at the moment it was saved, and the last good file with it.
``save`` now reads the bytes it is about to write with the reader's own checks and refuses, writing nothing, what
``load`` would refuse, in the same words. A mission whose robot's map gets a NaN says so in one line, stops as on a
full disk, and keeps that robot's last good file."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from estimation.errors import MapFileError
from estimation.landmark_map import LandmarkMap
from runtime.mission import Mission, MissionConfig
from runtime.onboard import Onboard
from tests.hardening.foreign_map import save_unchecked

_NAN, _INF = float("nan"), float("inf")


def _good_map() -> LandmarkMap:
    return LandmarkMap(np.zeros((2, 3)), np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 4), np.float32))


_SPOILERS = {   # one value or array a reader refuses (where the map has the landmarks, rows or fields it needs)
    "NaN position": lambda m: m.positions[:1, :1].fill(_NAN),
    "infinite position": lambda m: m.positions[-1:, 2:].fill(-_INF),
    "position beyond the bound": lambda m: m.positions[:1, 1:2].fill(2e6),
    "NaN descriptor": lambda m: m.descriptors[:1, :1].fill(_NAN),
    "covariance not positive definite": lambda m: m.covariances[-1:, 2:, 2:].fill(-1e-3),
    "covariance not symmetric": lambda m: m.covariances[:1, 0:1, 1:2].fill(0.5),
    "variance beyond the bound": lambda m: m.covariances[:1].__imul__(1e7),
    "NaN covariance": lambda m: m.covariances[:1, 1:2, 1:2].fill(_NAN),
    "duplicate ids": lambda m: m.ids.fill(3),
    "negative count": lambda m: m.counts[:1].fill(-1),
    "NaN in the trajectory": lambda m: m.trajectory[:1, 2:3].fill(_NAN),
    "trajectory beyond the bound": lambda m: m.trajectory[-1:, 1:2].fill(-2e6),
    "drift not semi-definite": lambda m: None if m.drift_covariances is None else m.drift_covariances[:1].fill(-1.0),
    "NaN drift origin": lambda m: None if m.drift_origins is None else m.drift_origins[:1].fill(_NAN),
    "sightings not semi-definite": lambda m: None if m.sighting_covariances is None
    else m.sighting_covariances[:1].fill(-1.0),
    "control character in the robot's name": lambda m: setattr(m, "robot", "a\nb"),
    "frame name too long": lambda m: setattr(m, "frame", "f" * 257),
    "clock of the wrong type": lambda m: m.metadata.update(clock=7),
    "negative footprint": lambda m: m.metadata.update(footprint_radius_m=-1.0),
    # arrays changed after construction (the dataclass does not freeze them): a wrong dtype or shape
    "complex descriptors": lambda m: setattr(m, "descriptors", m.descriptors.astype(np.complex64)),
    "one id short": lambda m: setattr(m, "ids", m.ids[:-1]),
    "seen_by of another fleet": lambda m: setattr(m, "seen_by", np.ones((len(m), len(m.robots) + 1), bool)),
}


@st.composite
def _maps(draw) -> LandmarkMap:
    """A sound map (which the reader may still refuse: near its bounds, at rounding), and in about half of them one
    spoiled value or array."""
    n = draw(st.integers(0, 5))
    d = draw(st.integers(1, 4))
    t = draw(st.integers(0, 3))

    def floats(shape, low, high):
        size = int(np.prod(shape))
        return np.array(draw(st.lists(st.floats(low, high), min_size=size, max_size=size)), float).reshape(shape)

    def covariances(smallest: float) -> np.ndarray:
        a = floats((n, 3, 3), -1.0, 1.0)
        return a @ np.swapaxes(a, 1, 2) + draw(st.floats(smallest, 1.0)) * np.eye(3)

    robots = ["robot1", "robot2"][: draw(st.integers(1, 2))]
    drift = draw(st.booleans())
    m = LandmarkMap(
        positions=floats((n, 3), -1e3, 1e3), covariances=covariances(1e-9),
        descriptors=floats((n, d), -1.0, 1.0).astype(np.float32),
        ids=draw(st.permutations(range(n))), counts=np.array(draw(st.lists(st.integers(0, 9), min_size=n,
                                                                              max_size=n)), int),
        robot=draw(st.sampled_from(["robot1", "Roboter-Ä 2"])), robots=robots,
        seen_by=np.array(draw(st.lists(st.booleans(), min_size=n * len(robots), max_size=n * len(robots))),
                         bool).reshape(n, len(robots)),
        trajectory=np.column_stack([np.arange(t, dtype=float), floats((t, 3), -1e3, 1e3)]),
        metadata=dict(draw(st.sampled_from([{}, {"true_start_pose": [1.0, 2.0, 0.5]}, {"footprint_radius_m": 0.3},
                                       {"clock": "sim"}, {"note": "free-form"}]))),
        drift_covariances=covariances(0.0) if drift else None,
        drift_origins=floats((n, 2), -1e3, 1e3) if drift else None,
        sighting_covariances=covariances(0.0) if draw(st.booleans()) else None)
    spoil = draw(st.sampled_from(sorted(_SPOILERS))) if draw(st.booleans()) else None
    if spoil is not None:
        _SPOILERS[spoil](m)
    return m


def _arrays(m: LandmarkMap) -> dict[str, np.ndarray | None]:
    return {key: getattr(m, key) for key in ("positions", "covariances", "descriptors", "ids", "counts", "seen_by",
                                             "trajectory", "drift_covariances", "drift_origins",
                                             "sighting_covariances")}


def _save_as_load_reads(m: LandmarkMap, folder, elsewhere) -> str | None:
    """Save ``m`` over a good map file in ``folder`` and write it unchecked in ``elsewhere``: whatever ``save``
    accepts, ``load`` returns equal, array by array; whatever the reader refuses in the unchecked file, ``save``
    refuses in the same words, naming its file, writing nothing and leaving the old file as it was. Returns the
    reader's refusal (None: read back)."""
    path, unchecked = folder / "map.npz", elsewhere / "map.npz"
    elsewhere.mkdir(parents=True, exist_ok=True)
    _good_map().save(path)
    before = path.read_bytes()
    save_unchecked(m, unchecked)       # what save wrote before session 46
    try:
        LandmarkMap.load(unchecked)
        refused = None
    except MapFileError as exc:
        refused = str(exc).removeprefix(f"{unchecked}: ")
    try:
        m.save(path)
    except MapFileError as exc:
        assert str(exc) == f"{path}: not written: {refused}" and "\n" not in str(exc)
        assert path.read_bytes() == before and [p.name for p in folder.iterdir()] == ["map.npz"]
        return refused
    assert refused is None, f"save wrote a file load refuses: {refused}"
    back = LandmarkMap.load(path)
    for key, array in _arrays(m).items():
        got = getattr(back, key)
        if array is None:
            assert got is None, key
        else:
            assert got.dtype == array.dtype and got.shape == array.shape and np.array_equal(got, array), key
    assert (back.robot, back.frame, back.robots, back.metadata) == (m.robot, m.frame, m.robots, m.metadata)
    return None


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=_maps())
def test_what_save_writes_load_reads_back_equal_and_what_load_refuses_save_refuses_writing_nothing(
        tmp_path_factory, m):
    refused = _save_as_load_reads(m, tmp_path_factory.mktemp("saved"), tmp_path_factory.mktemp("unchecked"))
    event("read back" if refused is None else "refused")


@pytest.mark.parametrize("spoil", sorted(_SPOILERS))
def test_each_spoiled_array_or_name_is_refused_by_save_as_load_refuses_it(tmp_path, spoil):
    """Every spoiler on one sound map with every optional member (the property's draws reach some of them rarely)."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3, 3))
    spd = a @ np.swapaxes(a, 1, 2) + 0.01 * np.eye(3)
    m = LandmarkMap(rng.uniform(-5, 5, (3, 3)), spd, rng.normal(size=(3, 4)).astype(np.float32), counts=[1, 2, 3],
                    trajectory=np.column_stack([np.arange(2.0), rng.normal(size=(2, 3))]), drift_covariances=spd,
                    drift_origins=rng.normal(size=(3, 2)), sighting_covariances=spd)
    assert _save_as_load_reads(m, tmp_path / "a", tmp_path / "b") is None   # sound, read back
    _SPOILERS[spoil](m)
    assert _save_as_load_reads(m, tmp_path / "c", tmp_path / "d") is not None


@pytest.mark.parametrize("spoil, field", [
    (lambda m: m.positions.__setitem__((1, 2), _NAN), "positions"),
    (lambda m: m.covariances.__setitem__(0, np.diag([1.0, 1.0, -1.0])), "covariances[0]"),
    (lambda m: m.trajectory.__setitem__((0, 1), _INF), "trajectory"),
])
def test_a_refused_save_names_file_and_field_and_keeps_the_old_file(tmp_path, spoil, field):
    path = tmp_path / "robot1.npz"
    m = _good_map()
    m.trajectory = np.zeros((2, 4))
    m.save(path)
    before = path.read_bytes()
    spoil(m)
    with pytest.raises(MapFileError) as error:
        m.save(path)
    assert str(error.value).startswith(f"{path}: not written: field '{field}'")
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["robot1.npz"]


def _nan_map(m: LandmarkMap) -> LandmarkMap:
    bad = m.subset(np.arange(len(m)))   # a copy: the filter's own arrays are left alone
    bad.positions[0, 0] = _NAN
    return bad


def test_a_mission_whose_map_gets_a_nan_says_so_in_one_line_and_keeps_the_last_good_file(tmp_path, monkeypatch):
    """robot2's map gets a NaN after its first saved snapshot with landmarks: that periodic save is refused (one
    event line naming the file and the field), the mission stops as on a full disk, its final save is refused too,
    and robot2.npz is the last good snapshot; robot1's maps are saved as ever."""
    current, final = Onboard.current_map, Onboard.final_map
    saved: list[LandmarkMap] = []

    def current_map(self):
        m = current(self)
        if self.robot != "robot2" or m is None or not len(m):
            return m
        if not saved:
            saved.append(m)
            return m
        return _nan_map(m)

    monkeypatch.setattr(Onboard, "current_map", current_map)
    monkeypatch.setattr(Onboard, "final_map", lambda self: _nan_map(final(self)) if self.robot == "robot2"
                        else final(self))
    events: list[str] = []
    config = MissionConfig(robots=2, seconds=30.0, seed=1, camera="synthetic", camera_rate=10.0, particles=10,
                           fusion_interval=0.0, map_save_interval=1.0, out=tmp_path, rerun="none")
    result = Mission(config, events=events.append).run()   # no exception: the robots stopped, the files closed

    file = tmp_path / "robot2.npz"
    assert saved, "robot2 never had a map with landmarks to save"
    periodic, at_end = result.failures
    for failure in (periodic, at_end):
        assert (failure.robot, failure.stage) == ("robot2", "map save")
        assert failure.error == f"MapFileError: {file}: not written: field 'positions' holds non-finite values"
    said = [e for e in events if e.startswith("FAILED: robot2: the map save stage failed")]
    assert len(said) == 2 and all("\n" not in e and str(file) in e for e in said)
    assert result.summary["sim_seconds"] < periodic.t + 0.5 < config.seconds   # the mission stopped there
    kept = LandmarkMap.load(file)                          # the last good snapshot, readable
    assert np.array_equal(kept.positions, saved[0].positions)
    assert not (tmp_path / "robot2.ply").exists() and str(file) not in result.summary["files"]
    assert len(LandmarkMap.load(tmp_path / "robot1.npz")) == result.summary["robots"]["robot1"]["landmarks"]
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
