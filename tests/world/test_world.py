"""The world against the NetLogo demo's (docs/world.md): map, vision, touch, actions, boundary, metrics."""

import gc
import math
import warnings

import numpy as np
import pytest

from services.vocabulary import BLACK, EMPTY, GREEN, RED
from services.world.world import (
    ACTIONS,
    SENSORS,
    MapError,
    World,
    WorldParams,
    generate_map,
    load_map,
    map_world,
    params_for,
)

SMELL = {BLACK: SENSORS.index("smell_black"), RED: SENSORS.index("smell_red"), GREEN: SENSORS.index("smell_green")}
PAIN, REWARD = SENSORS.index("pain"), SENSORS.index("reward")
NOTHING = np.zeros((1, len(ACTIONS)), np.uint8)


def test_default_map():
    p = WorldParams()
    grid = generate_map(p, seed=7)
    border = np.concatenate([grid[0], grid[-1], grid[:, 0], grid[:, -1]])
    assert (border == BLACK).all()
    inner = grid[1:-1, 1:-1]
    # 10 % red and 10 % green inside (2,223 patches: within 3 standard deviations)
    n = inner.size
    for colour in (RED, GREEN):
        assert abs((inner == colour).sum() - 0.1 * n) < 3 * math.sqrt(n * 0.09)
    # wall columns at x = 88 .. 118 from y = 4 up, except where red or green overwrote a cell
    for x in p.wall_columns:
        column = grid[x - p.x_min, 4 - p.y_min : -1]
        assert set(np.unique(column)) <= {BLACK, RED, GREEN} and (column == BLACK).mean() > 0.7
        assert (grid[x - p.x_min, 1:3] != BLACK).all()  # the gap under each column
    assert grid[102 - p.x_min, 30 - p.y_min] == EMPTY  # the start patch is cleared
    np.testing.assert_array_equal(grid, generate_map(p, seed=7))
    assert not np.array_equal(grid, generate_map(p, seed=8))


def corridor(cells: str, start=(1.0, 1.0), **kw):
    """A 1-agent world on a map: one row of `cells` (x from 1) inside a wall, facing east."""
    rows = ["#" * (len(cells) + 2), "#" + cells + "#", "#" * (len(cells) + 2)]
    grid = np.zeros((len(cells) + 2, 3), np.uint8)
    for y, row in enumerate(reversed(rows)):
        for x, ch in enumerate(row):
            grid[x, y] = {"#": BLACK, "R": RED, "G": GREEN, ".": EMPTY, "S": EMPTY}[ch]
    params = WorldParams(x_min=0, y_min=0, x_max=grid.shape[0] - 1, y_max=2, start=start, wall_columns=(), **kw)
    w = World(params, grid=grid)
    w.heading[:] = 90.0  # east
    return w


@pytest.mark.parametrize(
    "cells,colour,distance",
    [
        ("S..R....", RED, 2.6),  # patch 4 starts at x = 3.5: the first sample inside is 1 + 2.6 = 3.6
        ("S.G.R...", GREEN, 1.6),  # the first non-empty patch is the one seen
        ("S......", BLACK, None),  # the east wall at x = 8 is 7 away: beyond the view distance
        ("S..", BLACK, 2.6),
    ],
)
def test_vision_sees_the_first_patch_ahead(cells, colour, distance):
    w = corridor(cells)
    s = w.sense()[0]
    seen = {c: s[k] for c, k in SMELL.items() if not np.isnan(s[k])}
    if distance is None:
        assert seen == {}
    else:
        assert seen == {colour: pytest.approx(distance)}
    assert np.isnan(s[PAIN]) and np.isnan(s[REWARD])


def test_touching_a_noxious_patch_hurts_counts_once_and_pushes_in_training():
    w = corridor("SRR.....", start=(2.0, 1.0))
    s = w.sense()[0]
    assert s[PAIN] == 1.0
    assert w.metrics.collisions[0] == 0 and w.pos[0, 0] == 2.0  # sensing reads; the touch acts in act()
    w.act(NOTHING)
    assert w.metrics.collisions[0] == 1 and w.metrics.collisions_by_colour[0, RED] == 1
    assert w.pos[0, 0] == pytest.approx(2.5)  # pushed 0.5 forward (east)
    w.sense()
    w.act(NOTHING)  # x = 2.5 is in patch 3 (nearest centre, ties go up): another red patch
    assert w.metrics.collisions[0] == 2  # entering a second noxious patch is a second event
    w.sense()
    w.act(NOTHING)
    assert w.metrics.collisions[0] == 2  # pushed within patch 3: the same patch, no new event
    assert w.metrics.last_collision[0] == 1


def test_no_push_when_training_is_off():
    w = corridor("SR......", start=(2.0, 1.0))
    w.training = False
    assert w.sense()[0, PAIN] == 1.0
    w.act(NOTHING)
    assert w.pos[0, 0] == 2.0 and w.metrics.collisions[0] == 1


def test_food_is_eaten_and_rewards():
    w = corridor("SG......", start=(2.0, 1.0))
    assert w.sense()[0, REWARD] == 1.0
    assert w.sense()[0, REWARD] == 1.0  # sensing again finds it again: sensing eats nothing
    w.act(NOTHING)
    assert w.metrics.food[0] == 1 and w.grid[0, 2, 1] == EMPTY
    assert w.changes().tolist() == [[0, 2, 1, EMPTY]]
    assert np.isnan(w.sense()[0, REWARD])


def test_actions_follow_netlogo_headings():
    w = World(params_for("paper"), seed=3)
    w.heading[:] = 0.0  # north: +y
    x, y = w.pos[0]
    w.act(np.array([[0, 1]], np.uint8))
    assert w.pos[0] == pytest.approx([x, y + 1.0])
    w.act(np.array([[1, 0]], np.uint8))
    assert w.heading[0] == 5.0  # rotate right, paper step
    netlogo = World(params_for("netlogo"), seed=3)
    netlogo.heading[:] = 90.0
    netlogo.act(np.array([[1, 1]], np.uint8))  # both: rotate, then move along the new heading
    assert netlogo.heading[0] == 94.0
    assert netlogo.pos[0] == pytest.approx(
        [102 + 0.4 * math.sin(math.radians(94)), 30 + 0.4 * math.cos(math.radians(94))]
    )
    assert netlogo.metrics.distance[0] == pytest.approx(0.4)


def test_a_heading_set_between_ticks_is_the_one_sensed_and_moved_along():
    # the kernels keep each insect's sine and cosine while its heading stays, bit for bit
    w = corridor("S..R....", start=(2.0, 1.0))
    assert w.sense()[0, SMELL[RED]] == pytest.approx(1.6)  # east: patch 4 starts at x = 3.5
    w.heading[:] = 270.0  # west, set from outside
    seen = w.sense()[0]
    assert np.isnan(seen[SMELL[RED]]) and seen[SMELL[BLACK]] == pytest.approx(1.6)  # the wall at x = 0
    w.act(np.array([[0, 1]], np.uint8))  # move west
    assert w.pos[0] == pytest.approx([1.0, 1.0])
    w.heading[:] = 90.0
    w.act(np.array([[0, 1]], np.uint8))  # east, not along the heading kept from before
    assert w.pos[0] == pytest.approx([2.0, 1.0])


def test_leaving_the_arena_returns_to_start():
    w = corridor("S.......", start=(1.0, 1.0))
    w.pos[0] = (8.9, 1.0)
    w.act(np.array([[0, 1]], np.uint8))  # past x_max = 9
    assert tuple(w.pos[0]) == (1.0, 1.0) and w.metrics.resets[0] == 1


def test_learning_time_is_the_last_collision_before_w_free_ticks():
    w = corridor("SR......", start=(2.0, 1.0), learned_after=50)
    w.training = False  # stay on the red patch: no push
    for _ in range(10):
        w.sense()
        w.act(NOTHING)
    w.pos[0] = (5.0, 1.0)  # step off, onto empty floor facing the wall at 8
    for _ in range(10, 80):
        w.sense()
        w.act(NOTHING)
    assert w.metrics.collisions[0] == 1  # entering once; staying is not a new event
    # but every tick on it resets the count (NetLogo's error_free_counter): the last was tick 9
    assert w.metrics.last_noxious[0] == 9
    assert w.metrics.learned_at[0] == 9


def test_collision_bins_per_thousand_ticks():
    w = corridor("SR......", start=(2.0, 1.0))
    w.training = False
    for t in range(2000):
        if t == 1500:
            w.pos[0] = (4.0, 1.0)
        if t == 1600:
            w.pos[0] = (2.0, 1.0)
        w.sense()
        w.act(NOTHING)
    assert [b.tolist() for b in w.metrics.bins] == [[1], [1]]


def test_agents_have_their_own_arenas_or_share_one():
    own = World(agents=3, seed=5)
    assert not np.array_equal(own.grid[0], own.grid[1])
    np.testing.assert_array_equal(own.grid[1], generate_map(own.params, 6))  # agent a: seed + a
    shared = World(agents=2, seed=5, shared=True)
    assert shared.grid.shape[0] == 1
    # food eaten by one agent is gone for the other
    g = shared.grid[0]
    fx, fy = np.argwhere(g == GREEN)[0]
    shared.pos[0] = (fx + shared.params.x_min, fy + shared.params.y_min)
    shared.sense()
    shared.act(np.zeros((2, 2), np.uint8))
    assert shared.grid[0, fx, fy] == EMPTY and shared.metrics.food.tolist() == [1, 0]


def test_same_seed_same_world_and_headings():
    a, b = World(agents=4, seed=11), World(agents=4, seed=11)
    np.testing.assert_array_equal(a.grid, b.grid)
    np.testing.assert_array_equal(a.heading, b.heading)
    assert len(set(a.heading.tolist())) == 4


MAP = """\
; a small arena
##########
#S...R...#
#........#
#..G.....#
##########
"""


def test_map_file(tmp_path):
    path = tmp_path / "arena.txt"
    path.write_text(MAP)
    params, grid = map_world(path)
    assert grid.shape == (10, 5) and params.start == (1.0, 3.0)
    assert grid[5, 3] == RED and grid[3, 1] == GREEN and grid[0, 0] == BLACK and grid[1, 3] == EMPTY
    w = World(params, grid=grid, agents=2)
    np.testing.assert_array_equal(w.grid[0], grid)
    np.testing.assert_array_equal(w.pos, [[1.0, 3.0]] * 2)


@pytest.mark.parametrize(
    "text,problem",
    [
        ("####\n#S.#\n#..\n####\n", "line 3: row has 3 cells, the first row has 4"),
        ("####\n#SX#\n####\n", "line 2, column 3: unknown cell 'X'"),
        ("####\n#..#\n####\n", "no start 'S'"),
        ("####\n#SS#\n####\n", "line 2: a second start"),
        ("#####\n#.S.#\n#...#\n#.S.#\n#####\n", "line 4: a second start"),  # line 4 repeats line 2
        ("; a comment\n####\n#S.#\n\n####\n#..\n", "line 6: row has 3 cells"),
        ("", "empty map"),
    ],
)
def test_wrong_map_files_say_where(tmp_path, text, problem):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(MapError, match=f"^{path}: .*{problem}"):
        load_map(path)
    with pytest.raises(MapError, match="cannot read map file"):
        load_map(tmp_path / "missing.txt")
    (tmp_path / "picture.png").write_bytes(b"\x89PNG\r\n")
    with pytest.raises(MapError, match="not a text map"):
        load_map(tmp_path / "picture.png")


def test_a_map_file_is_closed_once_read(tmp_path):
    path = tmp_path / "map.txt"
    path.write_text("####\n#S.#\n####\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        load_map(path)
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]


def test_actions_of_another_shape_are_refused_and_other_integer_types_taken():
    w, same = World(params_for("paper"), agents=2, seed=3), World(params_for("paper"), agents=2, seed=3)
    with pytest.raises(ValueError, match=r"actions of shape \(1, 2\), expected \(2, 2\)"):
        w.act(np.array([[0, 1]], np.uint8))  # would have moved every agent by broadcasting
    assert w.tick == 0 and (w.pos == same.pos).all()
    w.act(np.array([[1, 1], [0, 1]], np.int64))
    same.act(np.array([[1, 1], [0, 1]], np.uint8))
    assert (w.pos == same.pos).all() and (w.heading == same.heading).all() and w.heading[0] != w.heading[1]
