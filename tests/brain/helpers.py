"""Small circuits and feed helpers for the engine tests."""

import numpy as np

from services.brain.circuit import build_circuit
from services.brain.engine import Engine


def phased(circuit, **options) -> Engine:
    """An engine with the phased semantics: the tests that pin its timing and STDP bookkeeping."""
    return Engine(circuit, semantics="phased", **options)


def relay_circuit(**types):
    """C and U relay neurons onto M: c_in -> C -> M (plastic, w 5), u_in -> U -> M (w 20), delays 3."""
    doc = {
        "name": "relay",
        "types": types,
        "neurons": {"C": "regular", "U": "regular", "M": types and next(iter(types)) or "regular"},
        "inputs": {"c_in": {"target": "C", "sensor": "c"}, "u_in": {"target": "U", "sensor": "u"}},
        "synapses": [
            {"from": "C", "to": "M", "weight": 5, "delay": 3, "plastic": True},
            {"from": "U", "to": "M", "weight": 20, "delay": 3},
        ],
    }
    return build_circuit(doc)


def run_with_events(engine: Engine, ticks: int, events: dict[int, dict[str, float]], agent=0):
    """Step `ticks` ticks, feeding {tick: {input name: value}}; returns spike ticks per node name."""
    names = engine.circuit.node_names
    spikes = {n: [] for n in names}
    for t in range(ticks):
        feed = None
        if t in events:
            feed = engine.no_feed.copy()
            for name, value in events[t].items():
                feed[agent, engine.circuit.input_index(name)] = value
        s = engine.step(feed)
        for k in np.flatnonzero(s[agent]):
            spikes[names[k]].append(t)
    return spikes


def random_feeds(seed, ticks, agents, inputs):
    """Sparse random feeds (ticks, agents, inputs): a value in [0, 4) 3 % of the time, else NaN."""
    rng = np.random.default_rng(seed)
    values = rng.random((ticks, agents, inputs)) * 4
    return np.where(rng.random((ticks, agents, inputs)) < 0.03, values, np.nan)
