"""The SpikingLab source's setup on NetLogo's stream: the arena it paints and the draws it makes.

No NetLogo runs here, so the arena of a seed has no outside oracle; the primitives it is made of
are checked against NetLogo's own tests (test_netlogo_random.py). These tests hold the build to
the source: which patches can be what, and the exact sequence of draws that the source's asks
make, written out from the source by hand (docs/netlogo-random.md).
"""

import dataclasses

import numpy as np
import pytest

from services.vocabulary import BLACK, EMPTY, GREEN, RED
from services.world.netlogo_random import NetLogoRandom
from services.world.netlogo_setup import build_insect, draw_world, spikinglab_setup
from services.world.world import World, WorldParams, params_for

COLUMNS = (88, 94, 100, 106, 112, 118)


class RecordingRandom(NetLogoRandom):
    """NetLogo's stream, noting each draw: ("int", n) for nextInt(n), ("long", n) for nextLong(n)."""

    def __init__(self, seed: int) -> None:
        self.calls: list[tuple[str, int]] = []
        super().__init__(seed)

    def next_int(self, n: int) -> int:
        self.calls.append(("int", n))
        return super().next_int(n)

    def next_long(self, n: int) -> int:
        self.calls.append(("long", n))
        return super().next_long(n)


def shuffle_draws(n: int) -> list[tuple[str, int]]:
    """An ask over n agents whose commands draw nothing: nextInt(n), nextInt(n - 1) .. nextInt(2)."""
    return [("int", k) for k in range(n, 1, -1)]


def test_draw_world_makes_the_sources_draws_in_its_order():
    rng = RecordingRandom(7850)
    draw_world(rng)
    # four border asks: rows y = 1 and y = 60 (x 80..120), columns x = 80 and x = 120 (y 1..60)
    expected = shuffle_draws(41) + shuffle_draws(41) + shuffle_draws(60) + shuffle_draws(60)
    # seven wall columns (x = 88 .. 124, y 4 .. 75 in a world of y <= 60); x = 124 has no patch
    expected += shuffle_draws(57) * 6
    # the inner patches (x 81..119, y 2..59): ask draws the next patch before each patch's random(10)
    n = 39 * 58
    expected += [("int", n)]
    expected += [d for k in range(n - 1, 1, -1) for d in (("int", k), ("long", 10))]
    expected += [("long", 10), ("long", 10)]
    assert rng.calls == expected


def test_setup_after_draw_world_makes_the_sources_draws():
    rng = RecordingRandom(7850)
    build_insect(rng)
    # 22 turtles created (2 neuron types, 9 neurons, 6 input neurons, the insect, 3 sensors, the
    # sight line): a colour and a heading each; 46 one-of-with look-ups shuffle a breed
    creations = sum(1 for a, b in zip(rng.calls, rng.calls[1:]) if a == ("int", 14) and b == ("int", 360))
    assert creations == 22
    assert all(kind == "int" for kind, _ in rng.calls)


def test_the_arena_is_the_sources():
    g = spikinglab_setup(7850).grid
    at = lambda x, y: g[x - 80, y - 1]  # noqa: E731
    # the border is wall: draw-world never repaints it
    assert all(at(x, 1) == at(x, 60) == BLACK for x in range(80, 121))
    assert all(at(80, y) == at(120, y) == BLACK for y in range(1, 61))
    # wall columns from y = 4: red or green may repaint them, nothing clears them
    for x in COLUMNS:
        assert all(at(x, y) in (BLACK, RED, GREEN) for y in range(4, 60))
        assert BLACK not in (at(x, 2), at(x, 3))
    # elsewhere inside: empty, red or green; and setup paints (102, 46) black (empty)
    inner = [at(x, y) for x in range(81, 120) if x not in COLUMNS for y in range(2, 60)]
    assert set(inner) <= {EMPTY, RED, GREEN}
    assert at(102, 46) == EMPTY


def test_red_and_green_are_each_a_tenth_of_the_inner_patches():
    # random(10) = 1 paints red, = 2 green: over 20 seeds each is 10 % within sampling error
    inner = np.concatenate([spikinglab_setup(seed).grid[1:-1, 1:-1].ravel() for seed in range(20)])
    for colour in (RED, GREEN):
        share = np.mean(inner == colour)
        assert abs(share - 0.1) < 4 * np.sqrt(0.1 * 0.9 / inner.size)


def test_same_seed_same_setup_and_other_seeds_differ():
    a, b, c = spikinglab_setup(7850), spikinglab_setup(7850), spikinglab_setup(7851)
    assert np.array_equal(a.grid, b.grid) and a.heading == b.heading
    assert not np.array_equal(a.grid, c.grid)
    assert a.heading == int(a.heading) and 0 <= a.heading < 360  # create-turtles: whole degrees


def test_world_takes_the_sources_arena_and_heading():
    setup = spikinglab_setup(7850)
    params = params_for("netlogo", start_heading=setup.heading)
    world = World(params, grid=setup.grid)
    assert np.array_equal(world.grid[0], setup.grid)
    assert world.heading[0] == setup.heading
    world.reset()
    assert world.heading[0] == setup.heading


def test_another_arena_size_is_refused():
    with pytest.raises(ValueError, match="80..120"):
        spikinglab_setup(7850, WorldParams(x_max=110))


def world_options(*argv: str):
    from services.options import config_from
    from services.world.service import WorldConfig, parser

    return config_from(parser().parse_args(list(argv)), WorldConfig).world


def test_netlogo_seed_option_builds_the_sources_arena_for_every_agent():
    from services.world.options import world_from

    setup = spikinglab_setup(7850)
    world = world_from(world_options("--preset", "netlogo", "--netlogo-seed", "7850", "--agents", "2"))
    assert all(np.array_equal(g, setup.grid) for g in world.grid)
    assert list(world.heading) == [setup.heading] * 2
    assert tuple(world.steps[0]) == (4.0, 0.4)


def test_netlogo_seed_and_a_map_are_refused_together(tmp_path):
    from services.world.options import world_from

    (tmp_path / "m.txt").write_text("###\n#S#\n###\n")
    with pytest.raises(ValueError, match="--netlogo-seed and --map"):
        world_from(world_options("--netlogo-seed", "1", "--map", str(tmp_path / "m.txt")))
    with pytest.raises(ValueError, match="outside -2147483648"):  # options made in Python, not parsed
        world_from(dataclasses.replace(world_options(), netlogo_seed=2**31))


def test_a_checkpoint_resumes_only_under_its_netlogo_seed(tmp_path):
    from services.world.checkpoint import CHECKPOINT, PENDING, keep_checkpoint, resume
    from services.world.options import world_from
    from services.world.results import Trajectory

    made = world_options("--netlogo-seed", "7850", "--ticks", "100")
    world = world_from(made)
    keep_checkpoint(tmp_path, made, world, Trajectory(world, made.ticks), "0123456789abcdef")
    (tmp_path / PENDING).replace(tmp_path / CHECKPOINT)
    other = world_options("--netlogo-seed", "7851", "--ticks", "100")
    with pytest.raises(ValueError, match=r"--netlogo-seed 7850 there, 7851 here"):
        resume(tmp_path, other, world_from(other), Trajectory(world_from(other), other.ticks))
    again = world_from(made)
    assert resume(tmp_path, made, again, Trajectory(again, made.ticks)) == "0123456789abcdef"
