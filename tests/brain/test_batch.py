"""Batch equivalence and determinism: A agents together == each alone; same feeds, same arrays."""

import numpy as np
import pytest

from services.brain.circuit import load_circuit
from services.brain.engine import PARALLEL_FROM

from .helpers import phased, random_feeds


@pytest.mark.parametrize("agents", [5, PARALLEL_FROM + 3])  # serial and parallel kernels
def test_agents_together_equal_each_alone(agents):
    c = load_circuit("insect").with_learning_rate(0.05)
    feeds = random_feeds(1, 3000, agents, len(c.inputs))
    together = phased(c, agents=agents)
    spikes = together.run(feeds)
    assert spikes[:, :, c.neuron_index("PAIN")].any()
    for a in sorted({0, 1, agents // 2, agents - 1}):
        alone = phased(c)
        np.testing.assert_array_equal(alone.run(feeds[:, a : a + 1]), spikes[:, a : a + 1])
        np.testing.assert_array_equal(alone.v, together.v[a : a + 1])
        np.testing.assert_array_equal(alone.w, together.w[a : a + 1])
    # agents with different inputs end with different weights
    assert not np.array_equal(together.w[0], together.w[1])


def test_same_feeds_give_identical_arrays():
    c = load_circuit("insect")
    feeds = random_feeds(7, 5000, 3, len(c.inputs))
    runs = []
    for _ in range(2):
        e = phased(c, agents=3)
        runs.append((e.run(feeds), e.v.copy(), e.w.copy(), e.state.counters.copy(), e.state.hist.copy()))
    for x, y in zip(*runs):
        np.testing.assert_array_equal(x, y)


def test_reset_restores_the_initial_state():
    c = load_circuit("insect")
    feeds = random_feeds(2, 2000, 1, len(c.inputs))
    e = phased(c)
    first = e.run(feeds)
    e.reset()
    np.testing.assert_array_equal(e.run(feeds), first)


def test_weights_get_and_set():
    c = load_circuit("insect")
    e = phased(c, agents=2)
    w = e.get_weights()
    w[:, c.synapse_index("RED", "PAIN")] = 12.5
    e.set_weights(w)
    assert e.w[1, c.synapse_index("RED", "PAIN")] == 12.5
    w[0, c.synapse_index("RED", "PAIN")] = 16.0  # above w_max of a plastic synapse
    with pytest.raises(ValueError, match="RED->PAIN"):
        e.set_weights(w)
    with pytest.raises(ValueError, match="shape"):
        e.set_weights(np.ones((3, len(c.synapses))))
    with pytest.raises(ValueError, match="shape"):
        e.step(np.zeros((2, 1)))


@pytest.mark.parametrize("semantics", ["phased", "netlogo"])
def test_run_in_one_call_equals_step_by_step(semantics):
    """run() steps all its ticks in one compiled call: the same spikes, potentials and weights as
    step() tick by tick, and it refuses feeds of another shape."""
    from services.brain.engine import Engine

    c = load_circuit("insect").with_learning_rate(0.05)
    feeds = random_feeds(2, 2000, 3, len(c.inputs))
    whole, stepped = Engine(c, agents=3, semantics=semantics, seed=4), Engine(c, agents=3, semantics=semantics, seed=4)
    spikes = whole.run(feeds)
    np.testing.assert_array_equal(spikes, np.array([stepped.step(f).copy() for f in feeds]))
    assert spikes[:, :, c.neuron_index("PAIN")].any()
    for name, array in whole.snapshot().items():
        np.testing.assert_array_equal(array, stepped.snapshot()[name])
    assert whole.tick == stepped.tick == 2000
    with pytest.raises(ValueError, match=r"feeds must have shape \(ticks, 3, 6\)"):
        whole.run(feeds[:, :2])


@pytest.mark.parametrize("agents", [3, PARALLEL_FROM + 3])  # serial and parallel kernels
def test_step_takes_any_float64_feed_of_its_shape(agents):
    """step() reads a feed in place whatever its strides and writeability, converts other types,
    and refuses other shapes and dimensions: the same ticks follow in every case."""
    from services.brain.engine import Engine

    c = load_circuit("insect").with_learning_rate(0.05)
    feeds = random_feeds(3, 300, agents, len(c.inputs))
    reference = Engine(c, agents=agents, semantics="phased").run(feeds)
    wide = np.full((300, agents, 2 * len(c.inputs)), 7.0)
    wide[:, :, ::2] = feeds  # every other column: strided views
    frozen = feeds.copy()
    frozen.flags.writeable = False
    ways = {
        "strided": wide[:, :, ::2],
        "read-only": frozen,
        "big-endian": feeds.astype(">f8"),
        "lists": [f.tolist() for f in feeds],
        "transposed copy": np.ascontiguousarray(feeds.transpose(0, 2, 1)).transpose(0, 2, 1),
    }
    for way, given in ways.items():
        e = Engine(c, agents=agents, semantics="phased")
        np.testing.assert_array_equal(np.array([e.step(f).copy() for f in given]), reference, err_msg=way)
    for wrong in (np.zeros((agents, len(c.inputs) + 1)), np.zeros(len(c.inputs)), np.zeros((1, agents, len(c.inputs)))):
        with pytest.raises(ValueError, match=r"feed must have shape"):
            e.step(wrong)
