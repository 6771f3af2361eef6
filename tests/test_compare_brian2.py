"""examples/compare_brian2.py feeds Brian2 what the engine benchmark feeds the engine: the same
sensor values (spikinglab/bench/feeds.py), and from them the same input spikes. (Brian2 itself is no dependency: the
comparison runs in a venv of its own, docs/results.md.)"""

import numpy as np

from services.brain.circuit import load_circuit
from services.brain.engine import Engine
from spikinglab.bench.feeds import random_feeds

from .examples import example


def test_brian2_is_fed_the_benchmarks_values_and_the_engines_input_spikes():
    compare, circuit = example("compare_brian2"), load_circuit("insect")
    feeds = random_feeds(np.random.default_rng(0), circuit, 400, 5)
    spiked = Engine(circuit, agents=5).run(feeds)[:, :, len(circuit.neuron_names) :]  # the input neurons'
    ticks, agents, inputs = np.nonzero(spiked)
    index, tick = compare.input_spikes(circuit, feeds)
    assert len(index) > 400  # every input, the kick among them
    assert sorted(zip(agents * len(circuit.inputs) + inputs, ticks)) == sorted(zip(index.tolist(), tick.tolist()))
