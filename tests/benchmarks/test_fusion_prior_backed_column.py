"""benchmarks/fusion_prior.py says which found alignments rest on their start prior (session 47): the column "maps
alone" and the summary's "prior-backed N of the found, M of the wrong".

The folder here is a demo folder made by hand, the rendered building's symmetry in small: both maps hold ``common``
of the demo world's features seen from the robots' configured starts, and ``twins`` more that each map holds once,
robot 2's turned by a half turn about the corridor's centre (fusion_prior's SYMMETRY_CENTRE) with the same
descriptor. Under the truth the common ones support, under the half turn the twins do: without a prior the pair is
ambiguous."""
from __future__ import annotations

import re

import numpy as np
import pytest

from benchmarks.fusion_prior import SYMMETRY_CENTRE, demo_table
from benchmarks.fusion_sim import load_world
from estimation.geometry import inverse, transform_points
from estimation.landmark_map import LandmarkMap

DIM = 64


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _folder(root, common: int, twins: int):
    world = load_world()
    rng = np.random.default_rng(5)
    pick = rng.choice(len(world.features), common + twins, replace=False)
    points = world.features[pick]
    cx, cy = SYMMETRY_CENTRE
    turned = points[common:] * [-1, -1, 1] + [2 * cx, 2 * cy, 0]           # a half turn about the centre
    desc = _unit(rng.normal(size=(common + twins, DIM)))
    out = root / f"c{common}t{twins}"
    out.mkdir()
    for robot, seen in (("robot1", points), ("robot2", np.vstack([points[:common], turned]))):
        start = np.asarray(world.start_poses[robot], float)
        p = transform_points(inverse(start), seen) + rng.normal(0, 0.01, seen.shape) * [1, 1, 0]
        m = LandmarkMap(p, np.eye(3)[None].repeat(len(p), 0) * 0.03 ** 2,
                        _unit(desc + rng.normal(0, 0.02, desc.shape)), robot=robot)
        m.metadata["true_start_pose"] = start.tolist()
        m.save(out / f"{robot}.npz")
    return out


def _row(text: str, prior: str) -> list[str]:
    line = next(r for r in text.splitlines() if r.startswith("| c") and f"| {prior} |" in r)
    return [c.strip() for c in line.strip("|").split("|")]


def _backed(text: str, prior: str) -> tuple[int, int, int, int]:
    """(found, wrong, prior-backed of the found, of the wrong) of the summary line of ``prior``."""
    m = re.search(rf"^- {re.escape(prior)}: found (\d+) of 1, wrong (\d+), .*?prior-backed (\d+) of the found, "
                  r"(\d+) of the wrong", text, re.MULTILINE)
    assert m, text
    return tuple(int(g) for g in m.groups())


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("demo")
    return _folder(root, common=30, twins=22), _folder(root, common=22, twins=30)


def test_the_configured_starts_settle_the_half_turn_and_the_table_says_the_prior_decided(folders, capsys):
    demo_table([folders[0]], 1.0, 0.3)
    out = capsys.readouterr().out
    assert _row(out, "none")[2].startswith("not found: ambiguous")
    row = _row(out, "configured starts")
    assert row[2].startswith("found:") and "WRONG" not in row[2]
    assert row[-1].startswith("PRIOR: ambiguous, rival ") and row[-1].endswith("(outside)")
    assert _backed(out, "configured starts") == (1, 0, 1, 0)


def test_a_wrong_prior_on_the_maps_strongest_hypothesis_is_found_wrong_and_counted_prior_backed(folders, capsys):
    """The twins outnumber the common landmarks: the maps' best is the half turn, ambiguous; a prior on it makes it
    found, wrong, and the summary counts it among the prior-backed wrong ones."""
    demo_table([folders[1]], 1.0, 0.3)
    out = capsys.readouterr().out
    assert _row(out, "none")[2].startswith("not found: ambiguous")
    assert "**WRONG**" in _row(out, "at the strongest wrong hypothesis (wrong)")[2]
    assert _backed(out, "at the strongest wrong hypothesis (wrong)") == (1, 1, 1, 1)
    assert "PRIOR: ambiguous" in _row(out, "at the strongest wrong hypothesis (wrong)")[-1]
