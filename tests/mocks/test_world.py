"""The simulated building: ray casts, collisions, line of sight, features, file errors, the robot registry."""

from __future__ import annotations

import copy
import json
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.world import DEFAULT_WORLD_PATH, Decoration, World, WorldFileError


@pytest.fixture(scope="module")
def world() -> World:
    return World.load()


def box_doc(**extra) -> dict:
    """A 10 × 4 m box room, one wall with a doorway, one poster."""
    doc = {
        "version": 1,
        "name": "box",
        "walls": [
            {"from": [0, 0], "to": [10, 0], "height": 2.5,
             "decorations": [{"kind": "poster", "s0": 2.0, "s1": 3.0, "z0": 1.0, "z1": 2.0, "side": 1, "seed": 5}]},
            {"from": [10, 0], "to": [10, 4]},
            {"id": "top", "from": [10, 4], "to": [0, 4], "openings": [[4.0, 6.0]]},
            {"from": [0, 4], "to": [0, 0]},
        ],
    }
    doc.update(extra)
    return doc


@pytest.fixture
def box() -> World:
    return World.from_dict(box_doc())


# ------------------------------------------------------------------ the packaged building
def test_packaged_building_matches_the_brief(world: World) -> None:
    xmin, ymin, xmax, ymax = world.bounds
    assert (xmax - xmin, ymax - ymin) == pytest.approx((35.0, 10.0))
    assert world.walls.shape[1] == 4 and world.wall_heights.shape == (len(world.walls),)
    assert np.all((world.wall_heights >= 2.5) & (world.wall_heights <= 3.0))
    kinds = {d.kind for d in world.decorations}
    assert {"poster", "door", "window", "notice", "door_frame", "baseboard"} <= kinds
    assert world.features.shape[1] == 3 and len(world.features) > 100
    assert world.feature_descriptors.shape == (len(world.features), 64)
    assert world.feature_descriptors.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(world.feature_descriptors, axis=1), 1.0, rtol=1e-5)
    for name in ("robot1", "robot2"):
        start = world.start_poses[name]
        assert start.shape == (3,) and world.routes[name].shape[1] == 2
        np.testing.assert_allclose(world.routes[name][0], start[:2])
    gap = np.linalg.norm(world.start_poses["robot1"][:2] - world.start_poses["robot2"][:2])
    assert 2.0 < gap < 10.0
    assert world.start_poses["robot1"][2] != world.start_poses["robot2"][2]


def test_routes_keep_clear_of_walls(world: World) -> None:
    for name, route in world.routes.items():
        points = np.concatenate([np.linspace(route[i], route[i + 1], 100) for i in range(len(route) - 1)])
        assert world.distance_to_walls(points).min() >= 0.6, name
        length = np.linalg.norm(np.diff(route, axis=0), axis=1).sum()
        assert 60 <= length / 0.35 <= 90, (name, length)


def test_features_lie_on_their_walls_below_wall_height(world: World) -> None:
    a, b = world.walls[world.feature_walls, :2], world.walls[world.feature_walls, 2:]
    e = b - a
    cross = e[:, 0] * (world.features[:, 1] - a[:, 1]) - e[:, 1] * (world.features[:, 0] - a[:, 0])
    np.testing.assert_allclose(cross / np.linalg.norm(e, axis=1), 0.0, atol=1e-9)
    assert np.all(world.features[:, 2] <= world.wall_heights[world.feature_walls] + 1e-9)


def test_features_are_deterministic_and_seeded_by_the_file() -> None:
    w1, w2 = World.load(), World.load()
    np.testing.assert_array_equal(w1.features, w2.features)
    np.testing.assert_array_equal(w1.feature_descriptors, w2.feature_descriptors)
    doc = json.loads(DEFAULT_WORLD_PATH.read_text())
    doc["feature_seed"] += 1
    w3 = World.from_dict(doc)
    np.testing.assert_array_equal(w1.features, w3.features)
    assert not np.allclose(w1.feature_descriptors, w3.feature_descriptors)
    # distinct corners are distinguishable: nearest other descriptor is clearly less similar than itself
    sim = w1.feature_descriptors @ w1.feature_descriptors.T
    np.fill_diagonal(sim, -1)
    assert sim.max() < 0.9


# ------------------------------------------------------------------ ray casts, hand-computed
def test_raycast_hand_computed_distances(box: World) -> None:
    origins = np.array([[3.0, 1.0], [3.0, 1.0], [3.0, 1.0], [3.0, 1.0], [1.0, 1.0], [5.0, 2.0]])
    angles = np.array([0.0, np.pi / 2, np.pi, -np.pi / 2, np.pi / 4, np.pi / 2])
    ranges, walls = box.raycast(origins, angles, 20.0)
    # east wall at x=10 -> 7; north wall y=4 -> 3; west x=0 -> 3; south y=0 -> 1; 45° from (1,1) hits y=4 at x=4
    np.testing.assert_allclose(ranges[:5], [7.0, 3.0, 3.0, 1.0, 3.0 * np.sqrt(2)])
    assert walls[0] == 1 and walls[3] == 0
    # straight up through the doorway (x=5 is inside the opening 4..6 of the top wall): nothing within 20 m
    assert ranges[5] == 20.0 and walls[5] == -1


def test_raycast_max_range_and_broadcast_origin(box: World) -> None:
    ranges, walls = box.raycast(np.array([3.0, 1.0]), np.array([0.0, np.pi]), np.array([5.0, 5.0]))
    np.testing.assert_allclose(ranges, [5.0, 3.0])
    np.testing.assert_array_equal(walls, [-1, 4])  # pieces: south, east, top ×2, west


def test_packaged_building_raycast_along_corridor(world: World) -> None:
    ranges, _ = world.raycast(np.array([[3.0, 5.0]] * 3), np.array([0.0, np.pi / 2, np.pi]), 50.0)
    np.testing.assert_allclose(ranges, [32.0, 1.25, 3.0])


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-5, 40), y=st.floats(-5, 15), angle=st.floats(-10, 10), max_range=st.floats(0.01, 60),
)
def test_ray_length_never_exceeds_max_range_and_hits_lie_on_their_wall(x, y, angle, max_range) -> None:
    world = _WORLD
    ranges, walls = world.raycast(np.array([[x, y]]), np.array([angle]), max_range)
    assert 0.0 <= ranges[0] <= max_range
    if walls[0] >= 0:
        hit = np.array([x, y]) + ranges[0] * np.array([np.cos(angle), np.sin(angle)])
        a, b = world.walls[walls[0], :2], world.walls[walls[0], 2:]
        s = np.clip(np.dot(hit - a, b - a) / np.dot(b - a, b - a), 0, 1)
        assert np.linalg.norm(a + s * (b - a) - hit) < 1e-6
    else:
        assert ranges[0] == max_range


_WORLD = World.load()


# ------------------------------------------------------------------ collisions and line of sight
def test_collides_with_disc(box: World) -> None:
    assert not box.collides(5.0, 2.0, 0.5)
    assert box.collides(0.3, 2.0, 0.33)  # 0.3 m from the west wall
    assert box.collides(9.8, 3.8, 0.33)  # corner
    assert not box.collides(5.0, 4.0, 0.9)  # in the doorway, 1 m from each jamb
    assert box.collides(5.0, 4.0, 1.01)


@settings(max_examples=100, deadline=None)
@given(x=st.floats(-2, 37), y=st.floats(-2, 12), radius=st.floats(0.01, 2))
def test_collides_agrees_with_distance(x, y, radius) -> None:
    d = _WORLD.distance_to_walls(np.array([x, y]))[0]
    assert _WORLD.collides(x, y, radius) == (d < radius)


def test_line_of_sight(box: World) -> None:
    p0 = np.array([5.0, 2.0])
    p1 = np.array([[8.0, 3.0], [5.0, 6.0], [2.0, 6.0], [10.0, 2.0], [12.0, 2.0]])
    # inside; through the doorway; through the top wall; touching the east wall (end point); past it
    np.testing.assert_array_equal(box.line_of_sight(p0, p1), [True, True, False, True, False])


def test_visible_features_face_and_fov(box: World) -> None:
    # the poster on the south wall (side +1 faces +y, into the room), corners at x 2..3, z 1..2
    looking_south = box.visible_features(np.array([2.5, 3.0, -np.pi / 2]), 0.5, np.radians(90), 10.0)
    looking_north = box.visible_features(np.array([2.5, 3.0, np.pi / 2]), 0.5, np.radians(90), 10.0)
    poster = np.isclose(box.features[:, 1], 0.0) & (box.features[:, 2] >= 1.0)
    assert looking_south[poster].all() and not looking_north[poster].any()
    outside = box.visible_features(np.array([2.5, -3.0, np.pi / 2]), 0.5, np.radians(90), 10.0)
    assert not outside[poster].any()  # behind the face


def test_doorway_pieces_and_frames(box: World) -> None:
    assert len(box.walls) == 5  # the top wall is split in two by its doorway
    frames = [d for d in box.decorations if d.kind == "door_frame"]
    assert len(frames) == 4  # two jambs × two faces
    assert all(isinstance(d, Decoration) and d.z0 == 0.0 for d in frames)


def test_arrays_are_read_only(world: World) -> None:
    with pytest.raises(ValueError):
        world.walls[0, 0] = 1.0


# ------------------------------------------------------------------ malformed files
@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d.pop("version"), "version"),
        (lambda d: d.update(version=7), "version"),
        (lambda d: d.update(name=""), "name"),
        (lambda d: d.update(walls=[]), "walls"),
        (lambda d: d["walls"][1].update(to=[10, "x"]), "walls[1].to"),
        (lambda d: d["walls"][1].update(to=[10, 0]), "walls[1].to"),
        (lambda d: d["walls"][1].pop("from"), "walls[1].from"),
        (lambda d: d["walls"][1].update(height=-1), "walls[1].height"),
        (lambda d: d["walls"][2].update(openings=[[4, 12]]), "walls[2](top).openings[0]"),
        (lambda d: d["walls"][0]["decorations"][0].update(side=0), "walls[0].decorations[0].side"),
        (lambda d: d["walls"][0]["decorations"][0].update(z1=9.0), "walls[0].decorations[0].z1"),
        (lambda d: d["walls"][0]["decorations"][0].pop("s0"), "walls[0].decorations[0].s0"),
        (lambda d: d.update(start_poses={"robot1": [1, 2]}), "start_poses.robot1"),
        (lambda d: d.update(routes={"robot1": [[1, 2]]}), "routes.robot1"),
        (lambda d: d.update(wals=[]), "wals"),
        (lambda d: d["walls"][1].update(heigth=2.0), "walls[1].heigth"),
        (lambda d: d["walls"][0]["decorations"][0].update(colour="red"), "walls[0].decorations[0].colour"),
    ],
)
def test_malformed_file_names_file_and_field(tmp_path, mutate, field) -> None:
    doc = copy.deepcopy(box_doc())
    mutate(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(WorldFileError) as info:
        World.load(path)
    assert isinstance(info.value, ValueError)
    assert str(path) in str(info.value) and field in str(info.value)
    assert info.value.field.startswith(field)


def test_underscore_keys_are_comments() -> None:
    doc = box_doc(_comment="hand-made")
    doc["walls"][0]["_note"] = "south"
    assert World.from_dict(doc).name == "box"


def test_decoration_across_a_doorway_is_rejected(tmp_path) -> None:
    doc = box_doc()
    doc["walls"][2]["decorations"] = [{"kind": "poster", "s0": 3.5, "s1": 4.5, "z0": 1, "z1": 2, "side": 1}]
    with pytest.raises(WorldFileError, match=r"walls\[2\]\(top\)\.decorations\[0\]"):
        World.from_dict(doc, source=tmp_path / "x.json")


def test_unreadable_and_invalid_json(tmp_path) -> None:
    with pytest.raises(WorldFileError, match="cannot read"):
        World.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"version": 1,\n "name": }')
    with pytest.raises(WorldFileError, match="line 2"):
        World.load(bad)


# ------------------------------------------------------------------ robot registry
def test_robot_registry(box: World) -> None:
    box.add_robot("a", [1.0, 2.0, 0.5])
    with pytest.raises(ValueError):
        box.add_robot("a", [0, 0, 0])
    pose = box.pose("a")
    pose[0] = 99.0  # a copy: the world is untouched
    np.testing.assert_array_equal(box.pose("a"), [1.0, 2.0, 0.5])
    box.set_pose("a", np.array([3.0, 2.0, 0.0]))
    assert box.robot_names() == ["a"]
    box.remove_robot("a")
    box.remove_robot("a")
    with pytest.raises(KeyError):
        box.pose("a")
    with pytest.raises(KeyError):
        box.set_pose("a", [0, 0, 0])


def test_robot_registry_is_thread_safe(box: World) -> None:
    def worker(k: int) -> None:
        name = f"r{k}"
        box.add_robot(name, [k, k, 0])
        for i in range(200):
            box.set_pose(name, [k, k, i])
            assert box.pose(name)[0] == k
        box.remove_robot(name)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert box.robot_names() == []


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-2, 37), min_size=4, max_size=4))
def test_line_of_sight_is_symmetric_and_agrees_with_raycast(coords) -> None:
    p0, p1 = np.array(coords[:2]), np.array(coords[2:])
    forward = _WORLD.line_of_sight(p0, p1[None])[0]
    assert forward == _WORLD.line_of_sight(p1, p0[None])[0]
    length = np.linalg.norm(p1 - p0)
    if length > 1e-3:
        ranges, _ = _WORLD.raycast(p0, np.array([np.arctan2(*(p1 - p0)[::-1])]), length)
        if ranges[0] < length - 1e-3 and ranges[0] > 1e-3:  # a wall clearly between: blocked
            assert not forward
        if ranges[0] >= length:  # nothing up to p1: visible
            assert forward


@pytest.mark.parametrize(("content", "said"), [
    (b"", "invalid JSON: Expecting value"),               # a JSON error at a place names it: line 1 column 1
    (b"\xff\xfe not text", "not UTF-8 text: "),
    (b"[" * 100_000, "JSON nested too deeply"),
    (b"1" * 5000, "invalid JSON: "),                       # more than 4300 digits: Python's int limit
    (None, "cannot read: "),
])
def test_a_file_that_is_no_world_file_reads_naturally(tmp_path, content, said) -> None:
    """The whole-file problems said '<file>' where a field goes ('bad.json: <file>: cannot read: ...')."""
    path = tmp_path / "bad.json"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(WorldFileError) as info:
        World.load(path)
    message = str(info.value)
    assert "<file>" not in message and said in message, message
    assert message.startswith(f"{path}: "), message
    if info.value.field == "":
        assert message.startswith(f"{path}: {said.split(':')[0]}"), message
