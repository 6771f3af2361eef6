"""The netlogo engine's `--order netlogo-stream`: the compiled Mersenne Twister against the Python
emulation of NetLogo's (services/world/netlogo_random.py), and each tick's draws against a
reference built from that emulation's shufflerator and the spikes and pulses the engine reports."""

import numpy as np
import pytest

from services.brain.circuit import load_circuit
from services.brain.engine import Engine
from services.brain.netlogo_stream import SOURCE_NEURONS, STREAM_INDEX, next_ints, stream_row
from services.loop import evaluate
from services.world.netlogo_random import MersenneTwister, NetLogoRandom
from services.world.netlogo_setup import spikinglab_setup

BOUNDS = [1, 2, 3, 5, 6, 7, 8, 9, 10, 14, 360, 1 << 16, 1 << 30, (1 << 30) + 1, 2**31 - 1, 2262, 1_000_003]


@pytest.mark.parametrize("seed", [0, 1, 7850, -5, 2**31 - 1, -(2**31)])
def test_compiled_next_int_is_netlogo_random_s(seed):
    """Ten thousand draws (several twists), bounds drawn from powers of two, near them and others."""
    rng = MersenneTwister(seed)
    rng.next_word()  # start mid-way through the words: the index travels with them
    stream = stream_row(*rng.state(), neurons=9)[None].copy()
    bounds = np.random.default_rng(abs(seed) % 1000).choice(BOUNDS, 10_000)
    got = next_ints(stream, 0, bounds)
    assert got.tolist() == [rng.next_int(int(b)) for b in bounds]
    words, index = rng.state()
    assert stream[0, :STREAM_INDEX].tolist() == words and stream[0, STREAM_INDEX] == index


def reference_tick(rng: NetLogoRandom, circuit, busy: np.ndarray, spiked: np.ndarray) -> list[int]:
    """One tick's draws of the SpikingLab source (docs/netlogo-random.md), made with the Python
    emulation: the world's two asks over 3 sensors, ask inputneurons, then ask normalneurons, each
    turn asking a spike's outgoing synapses and then those with pulses in flight (in flight at the
    tick's start, or sent now). Returns the neurons in the order of their turns."""
    n_net = len(circuit.synapses) - len(circuit.inputs)
    for _ in range(2):
        list(rng.ask_order(range(3)))
    list(rng.ask_order(range(len(circuit.inputs))))
    turns = []
    for n in rng.ask_order([circuit.neuron_index(name) for name in SOURCE_NEURONS]):
        turns.append(n)
        out = [s for s in range(n_net) if circuit.synapses[s].pre == n]
        if spiked[n]:
            list(rng.ask_order(out))
        list(rng.ask_order([s for s in out if busy[s] or spiked[n]]))
    return turns


def test_each_tick_draws_what_the_source_draws():
    """For 400 ticks of random feeds: the engine's turns are the reference's, and its stream is
    the reference's after every tick (the same number of draws)."""
    circuit = load_circuit("insect")
    engine = Engine(circuit, order="netlogo-stream", netlogo_seed=7850)
    rng = spikinglab_setup(7850).stream
    feeds = np.random.default_rng(3).integers(0, 4, (400, 1, len(circuit.inputs))).astype(float)
    feeds[np.random.default_rng(4).random(feeds.shape) < 0.7] = np.nan
    spikes = 0
    for feed in feeds:
        busy = np.any(engine.state.ring[:, :, 0], axis=0)
        spiked = engine.step(feed)[0]
        spikes += spiked[: engine.n_neurons].sum()
        assert engine.turns[0].tolist() == reference_tick(rng, circuit, busy, spiked)
        words, index = rng.state()
        assert engine.state.stream[0, :STREAM_INDEX].tolist() == words and engine.state.stream[0, STREAM_INDEX] == index
    assert spikes > 100  # the ticks had spikes and pulses to draw for


def test_a_population_and_a_reset_start_from_the_setup_s_stream():
    circuit = load_circuit("insect")
    engine = Engine(circuit, agents=3, order="netlogo-stream", netlogo_seed=7850)
    first = [engine.step().copy() for _ in range(50)], engine.turns.copy()
    engine.reset()
    again = [engine.step().copy() for _ in range(50)], engine.turns.copy()
    assert all((a == b).all() for a, b in zip(first[0], again[0])) and (first[1] == again[1]).all()
    assert (engine.turns == engine.turns[0]).all()  # every agent: the one stream of random-seed 7850


def test_the_run_is_deterministic_and_not_the_random_order_s():
    options = {"preset": "netlogo", "netlogo_seed": 7850}
    runs = [evaluate({"a_plus": 0.02}, 20_000, [0], order="netlogo-stream", **options) for _ in range(2)]
    other = evaluate({"a_plus": 0.02}, 20_000, [0], order="random", **options)
    assert all((runs[0][k] == runs[1][k]).all() for k in runs[0])
    assert any((runs[0][k] != other[k]).any() for k in ("collisions", "food"))


@pytest.mark.parametrize(
    "options, message",
    [
        ({"order": "netlogo-stream"}, "needs --semantics netlogo and --netlogo-seed N"),
        ({"order": "netlogo-stream", "semantics": "phased", "netlogo_seed": 1}, "needs --semantics netlogo"),
        ({"order": "netlogo-stream", "netlogo_seed": 1, "circuit": "two_actions"}, "the SpikingLab source's"),
    ],
)
def test_refused_in_one_line(options, message):
    circuit = load_circuit(options.pop("circuit", "insect"))
    with pytest.raises(ValueError, match=message) as refused:
        Engine(circuit, **options)
    assert "\n" not in str(refused.value)
