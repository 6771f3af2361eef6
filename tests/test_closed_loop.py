"""The closed loop: the same seed gives the same run in one process and across two processes."""

import numpy as np
import pytest

from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.bus import keys
from services.bus.schemas import BrainLayout
from services.loop import brain_for, closed_loop
from services.world.world import World, params_for

from .processes import Watcher, endpoint, finish, world_and_brain

TICKS, SEED, AGENTS = 3000, 5, 2


def inprocess_run(semantics):
    world = World(params_for("paper"), agents=AGENTS, seed=SEED)
    brain = brain_for(world, load_circuit("insect").with_learning_rate(0.04), semantics=semantics)
    pos, sensed, spikes = [], [], []

    def keep(t):
        pos.append(world.pos.copy())
        sensed.append(world.sensors.copy())
        spikes.append(brain.engine.spiked.copy())

    closed_loop(world, brain, TICKS, keep)
    return np.array(pos), np.array(sensed), np.array(spikes), brain.engine.get_weights(), world.metrics


def bus_run(tmp_path, semantics):
    """The same run as world and brain processes over Zenoh: the world's and the brain's state messages."""
    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    watcher = Watcher([world_ep, brain_ep], [keys.world_state("det"), keys.brain_state("det")])
    try:
        world, brain = world_and_brain(
            tmp_path,
            ["--group", "det", "--ticks", TICKS, "--seed", SEED, "--agents", AGENTS, "--out", tmp_path],
            # the netlogo order's seed comes from the world's messages
            ["--group", "det", "--a-plus", 0.04, "--save", tmp_path / "weights.npz", "--semantics", semantics],
        )
        assert finish(world, 120, tmp_path / "world.log") == 0
        assert finish(brain, 30, tmp_path / "brain.log") == 0
    finally:
        watcher.close()
    assert watcher.bad == []
    return watcher.messages[keys.world_state("det")], watcher.messages[keys.brain_state("det")]


@pytest.mark.parametrize("semantics", ["phased", "netlogo"])  # netlogo: its random order comes from the seed too
def test_same_seed_same_run_in_one_process_and_across_the_bus(tmp_path, semantics):
    pos, sensed, spikes, weights, metrics = inprocess_run(semantics)
    assert metrics.collisions.sum() > 0 and spikes.sum() > 0  # something happened
    world_states, (layout, *brain_states) = bus_run(tmp_path, semantics)
    assert isinstance(layout, BrainLayout) and layout.nodes == load_circuit("insect").node_names
    assert brain_states[-1].final and not any(m.final for m in brain_states[:-1])
    # batches of consecutive ticks: every tick, in order, none lost
    world_ticks = [m.tick + k for m in world_states for k in range(m.pos.shape[0])]
    brain_ticks = [m.tick + k for m in brain_states for k in range(m.spiked.shape[0])]
    assert world_ticks == list(range(TICKS)) and brain_ticks == list(range(TICKS))
    bus_pos = np.concatenate([m.pos.numpy("pos", "<f8", 3) for m in world_states])
    bus_spikes = np.concatenate([m.spiked.numpy("spiked", "|u1", 3) for m in brain_states]).astype(bool)
    np.testing.assert_array_equal(bus_pos, pos)  # bit for bit
    # the recorder's sensors of tick t are those the brain stepped on in tick t
    np.testing.assert_array_equal(np.concatenate([m.sensors.numpy("sensors", "<f8", 3) for m in world_states]), sensed)
    np.testing.assert_array_equal(bus_spikes, spikes)
    np.testing.assert_array_equal(load_weights(tmp_path / "weights.npz", load_circuit("insect")), weights)
    np.testing.assert_array_equal(brain_states[-1].weights.numpy("weights", "<f8", 2), weights)  # the final ones
