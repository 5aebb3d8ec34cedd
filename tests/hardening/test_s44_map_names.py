"""Map files whose robot or frame name holds a control character (session 44, A). The names are printed (`p3at fuse`'s
report, review, the viewer): a map saved with robot 'evil\\x1b[2J\\nX' made `p3at fuse` clear the user's screen and
print its map line over two lines. The reader now refuses such a name, one line naming file and field; any
printable name (accents, spaces, CJK) reads as before. The writer refuses to write a name its reader refuses
(writing nothing), so such a file comes from elsewhere: the tests write it member by member."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimation.errors import MapFileError
from estimation.landmark_map import LandmarkMap
from tests.datasets.conftest import run_cli
from tests.hardening.foreign_map import save_unchecked


def _map(robot: str = "robot1", frame: str = "map") -> LandmarkMap:
    rng = np.random.default_rng(0)
    n = 12
    a = rng.normal(size=(n, 3, 3)) * 0.1
    return LandmarkMap(positions=rng.uniform(-5, 5, (n, 3)), covariances=a @ np.swapaxes(a, 1, 2) + 0.01 * np.eye(3),
                       descriptors=rng.normal(size=(n, 16)).astype(np.float32), robot=robot, frame=frame)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.text(min_size=1, max_size=20), field=st.sampled_from(["robot", "frame"]))
def test_a_name_reads_back_or_is_refused_in_one_line(tmp_path_factory, name, field):
    path = tmp_path_factory.mktemp("m") / "map.npz"
    save_unchecked(_map(**{field: name}), path)
    if name.isprintable():
        assert getattr(LandmarkMap.load(path), field) == name
    else:
        with pytest.raises(MapFileError) as error:
            LandmarkMap.load(path)
        message = str(error.value)
        assert message.startswith(str(path)) and f"meta.{field}" in message and "\n" not in message
        assert "control character" in message


def test_fuse_refuses_such_a_map_before_printing_its_name(tmp_path):
    good, evil = tmp_path / "good.npz", tmp_path / "evil.npz"
    _map().save(good)
    save_unchecked(_map(robot="evil\x1b[2J\nX"), evil)
    status, out, err = run_cli("fuse", str(good), str(evil), "--out", str(tmp_path / "fused.npz"))
    assert status == 2 and len(err.strip().splitlines()) == 1 and "meta.robot" in err and str(evil) in err
    assert "\x1b" not in out + err and not (tmp_path / "fused.npz").exists()


def test_printable_names_of_every_kind_still_read(tmp_path):
    for name in ("robot 1", "Roboter-Ä", "机器人", "r" * 256):
        _map(robot=name).save(tmp_path / "m.npz")
        assert LandmarkMap.load(tmp_path / "m.npz").robot == name


@pytest.mark.parametrize("field,name", [("robot", "evil\x1b[2J\nX"), ("frame", "a\rb"), ("robot", "r" * 257)])
def test_the_writer_refuses_a_name_its_reader_refuses_and_writes_nothing(tmp_path, field, name):
    path = tmp_path / "map.npz"
    _map().save(path)
    before = path.read_bytes()
    with pytest.raises(MapFileError) as error:
        _map(**{field: name}).save(path)
    assert str(error.value).startswith(str(path)) and f"meta.{field}" in str(error.value)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["map.npz"]
