"""The fused loop in blocks of agents (each block a whole stretch on a thread of its own) gives
what the per-tick loop gives, bit for bit: metrics, collision bins, poses, weights, potentials."""

import numpy as np
import pytest

from services.loop import closed_loop, fused_loop, population
from services.world.world import World


def state(world, brain) -> list[np.ndarray]:
    m, engine = world.metrics, brain.engine
    metrics = [m.collisions, m.learned_at, m.food, m.distance, m.resets, np.array(m.bins)]
    return metrics + [world.pos, world.heading, world.grid, engine.w, engine.v, engine.snapshot()["hist"]]


@pytest.mark.parametrize("semantics", ["netlogo", "phased"])
def test_blocks_give_the_per_tick_loops_result(semantics):
    settings = {"a_plus": [0.04, 0.02], "a_minus": [0.04, 0.03], "move_step": [1.0, 0.7]}
    ticks = 1300  # a bin's end inside
    per_tick = population(settings, range(7), semantics=semantics)
    closed_loop(*per_tick, ticks, on_tick=lambda t: None)
    for blocks in (1, 3):
        blocked = population(settings, range(7), semantics=semantics)
        fused_loop(*blocked, 700, blocks=blocks)
        fused_loop(*blocked, ticks - 700, blocks=blocks)
        for a, b in zip(state(*per_tick), state(*blocked)):
            assert np.array_equal(a, b)
        assert blocked[1].engine.tick == ticks


def test_a_shared_arena_runs_in_one_block():
    world = World(agents=4, shared=True)
    _, brain = population({}, range(4))
    with pytest.raises(ValueError, match="blocks: >= 1, and 1 for a shared arena"):
        fused_loop(world, brain, 10, blocks=2)
