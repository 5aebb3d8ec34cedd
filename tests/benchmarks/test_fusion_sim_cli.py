"""benchmarks/fusion_sim.py's command line: the maps go to ``--out``, never into the data set folder it reads."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.fusion_sim import main
from estimation.landmark_map import LandmarkMap
from tests.datasets.conftest import write_mrclam


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A synthetic MRCLAM folder with five robots (each driving the same circle among the same landmarks)."""
    folder = tmp_path_factory.mktemp("mrclam")
    for robot in range(1, 6):
        write_mrclam(folder, robot=robot, seconds=30.0)
    return folder


def _listing(folder):
    return sorted((p.relative_to(folder), p.stat().st_size, p.stat().st_mtime_ns) for p in folder.rglob("*"))


def test_the_five_maps_are_written_into_the_output_folder(dataset, tmp_path, capsys):
    before = _listing(dataset)
    out = tmp_path / "maps"
    assert main(["mrclam", "--data", str(dataset), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == [f"robot{r}.npz" for r in range(1, 6)]
    m = LandmarkMap.load(out / "robot3.npz")
    assert m.robot == "robot3" and len(m) >= 3 and np.all(np.isfinite(m.positions))
    assert m.metadata["external_ids"]
    assert capsys.readouterr().out.count("landmarks\n") == 5
    assert _listing(dataset) == before


@pytest.mark.parametrize("inside", [".", "maps", "maps/deeper", "maps/../other"])
def test_an_output_folder_that_is_the_data_set_or_inside_it_is_refused_in_one_line(dataset, inside, capsys):
    before = _listing(dataset)
    out = dataset / inside
    assert main(["mrclam", "--data", str(dataset), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and "inside the data set folder" in captured.err and "--out" in captured.err
    assert _listing(dataset) == before


def test_a_symbolic_link_into_the_data_set_is_refused_too(dataset, tmp_path, capsys):
    link = tmp_path / "link"
    link.symlink_to(dataset, target_is_directory=True)
    before = _listing(dataset)
    assert main(["mrclam", "--data", str(dataset), "--out", str(link / "maps")]) == 2
    assert "inside the data set folder" in capsys.readouterr().err
    assert _listing(dataset) == before


def test_a_sibling_folder_whose_name_starts_like_the_data_set_is_not_inside_it(dataset, capsys):
    out = dataset.parent / (dataset.name + "-maps")
    assert main(["mrclam", "--data", str(dataset), "--out", str(out)]) == 0
    assert len(list(out.glob("robot*.npz"))) == 5


def test_a_missing_data_set_is_one_line_and_creates_no_output_folder(tmp_path, capsys):
    out = tmp_path / "maps"
    assert main(["mrclam", "--data", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a folder" in err
    assert not out.exists()


def test_the_old_positional_output_is_no_longer_accepted(dataset, capsys):
    """``fusion_sim.py mrclam DIR`` wrote into DIR; pointed at the data set it wrote there. Now --out is required."""
    before = _listing(dataset)
    with pytest.raises(SystemExit) as exit_:
        main(["mrclam", str(dataset)])
    assert exit_.value.code == 2 and "--out" in capsys.readouterr().err
    assert _listing(dataset) == before
