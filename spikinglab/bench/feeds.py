"""The engine benchmarks' sensor input, in a module of its own: without numba, so that a comparison
run where numba is not installed (examples/compare_brian2.py) feeds the same values."""

import numpy as np

FEED_PROBABILITY = 0.3  # chance per tick that a sensor feeds its input neuron a value in [0, 4)


def random_feeds(rng, circuit, ticks, agents):
    """Random sensor values for the sensor-bound inputs only (the pacemaker kick stays the circuit's)."""
    feeds = np.full((ticks, agents, len(circuit.inputs)), np.nan)
    cols = list(circuit.sensors.values())
    shape = (ticks, agents, len(cols))
    feeds[:, :, cols] = np.where(rng.random(shape) < FEED_PROBABILITY, rng.random(shape) * 4.0, np.nan)
    return feeds
