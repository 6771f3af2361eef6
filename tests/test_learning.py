"""The insect learns (the paper's Table 1 and its account of training; docs/results.md): fewer
collisions, black and red associated with pain."""

import numpy as np

from services.brain.circuit import load_circuit
from services.loop import brain_for, closed_loop
from services.world.world import World, params_for

SEEDS = 6  # arenas 0..5: the default seed and the next five, fixed before looking at results


def test_insect_learns_to_avoid_walls_and_predators():
    circuit = load_circuit("insect").with_learning_rate(0.04)
    world = World(agents=SEEDS, seed=0)
    brain = brain_for(world, circuit)
    closed_loop(world, brain, 40_000)
    bins = np.array(world.metrics.bins)  # [40, agents]
    first, last = bins[:10].sum(axis=0), bins[-10:].sum(axis=0)
    assert (first > 20).all()  # it did collide early on
    assert (last <= first / 2).all(), f"first quarter {first}, last quarter {last}"
    w = {
        name: brain.engine.w[:, circuit.synapse_index(*name.split("->"))]
        for name in ("BLACK->PAIN", "RED->PAIN", "GREEN->PAIN", "BLACK->REWARD")
    }
    assert (w["BLACK->PAIN"] > 5).all() and (w["RED->PAIN"] > 5).all()
    assert (w["GREEN->PAIN"] < 5).all()
    assert (w["BLACK->PAIN"] > w["BLACK->REWARD"]).all()  # black now drives turning, not moving on
    assert (world.metrics.food > 0).all()  # while it keeps finding food


def test_training_off_leaves_the_weights_alone():
    circuit = load_circuit("insect")
    world = World(agents=2, seed=3, training=False)
    brain = brain_for(world, circuit)
    trained = brain.engine.get_weights()
    trained[:, circuit.synapse_index("BLACK", "PAIN")] = 12.0  # as a trained insect might have
    brain.engine.set_weights(trained)
    closed_loop(world, brain, 5000)
    assert world.metrics.collisions.sum() > 0 or world.metrics.food.sum() > 0  # it lived
    np.testing.assert_array_equal(brain.engine.get_weights(), trained)


def test_the_default_run_learns_within_its_ticks():
    # `spikinglab run` with its defaults: seed 0, 100,000 ticks, A+ = A- = 0.02, paper steps, netlogo semantics
    world = World(params_for("paper"), agents=1, seed=0)
    brain = brain_for(world, load_circuit("insect"))
    closed_loop(world, brain, 100_000)
    assert 0 < world.metrics.learned_at[0] <= 95_000  # its 5,000 collision-free ticks end within the run
    bins = np.array(world.metrics.bins)[:, 0]
    assert bins[-25:].sum() * 10 < bins[:25].sum()  # collisions fell more than tenfold, first to last quarter
