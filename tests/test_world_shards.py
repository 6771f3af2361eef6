"""A sharded world: N world processes each step a slice of the population, as one world would."""

import numpy as np
import pytest

from services.brain.circuit import load_circuit
from services.loop import brain_for, closed_loop
from services.world.options import WorldOptions, world_from

TICKS, SEED, AGENTS = 3000, 3, 7  # 7 agents: world slices 0-2 and 3-6, brain slices 0-1, 2-3 and 4-6


def options(tmp_path, agents=AGENTS, shared=False) -> WorldOptions:
    study = tmp_path / "study.csv"
    np.savetxt(study, np.c_[1 - 0.05 * np.arange(agents)], delimiter=",", header="move_step", comments="")
    return WorldOptions(
        ticks=TICKS,
        seed=SEED,
        agents=agents,
        shared=shared,
        preset="paper",
        map=None,
        no_training=False,
        learned_after=5000,
        params=study,
    )


def test_a_sliced_world_steps_the_same_insects_as_the_whole(tmp_path):
    circuit = load_circuit("insect").with_learning_rate(0.04)
    whole = world_from(options(tmp_path))
    brain = brain_for(whole, circuit)
    closed_loop(whole, brain, TICKS)
    slices = [world_from(options(tmp_path), shard=(i, 2)) for i in (1, 2)]
    assert [w.agents for w in slices] == [3, 4] and list(slices[1].numbers) == [3, 4, 5, 6]
    for world in slices:
        closed_loop(world, brain_for(world, circuit), TICKS)
    assert sum(whole.metrics.collisions) > 0
    for name in ("collisions", "food", "distance", "resets", "learned_at"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(w.metrics, name) for w in slices]), getattr(whole.metrics, name), err_msg=name
        )
    np.testing.assert_array_equal(np.concatenate([w.pos for w in slices]), whole.pos)


def test_a_shared_arena_is_not_sharded(tmp_path):
    with pytest.raises(ValueError, match="--shared arena meet"):
        world_from(options(tmp_path, shared=True), shard=(1, 2))
    with pytest.raises(ValueError, match="more world shards than agents"):
        world_from(options(tmp_path, agents=2), shard=(1, 3))
