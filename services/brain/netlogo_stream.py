"""NetLogo's random stream, compiled: the netlogo engine's `--order netlogo-stream` draws its turns,
and every other number the SpikingLab source draws in a tick, from it (docs/netlogo-random.md).

The generator is services/world/netlogo_random.py's MersenneTwister (MT19937 with NetLogo's
nextInt), here as numba functions over a uint32 row per agent: its 624 words, then the index of
the next word to temper (STREAM_INDEX), then the turn order of the agent's last tick
(STREAM_TURNS..). tests/brain/test_netlogo_stream.py compares long sequences of both.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from services.world.netlogo_setup import spikinglab_setup

from .circuit import Circuit

N, M = 624, 397  # MT19937's words and its twist offset
STREAM_INDEX = N  # stream[a, STREAM_INDEX]: the index of agent a's next word
STREAM_TURNS = N + 1  # stream[a, STREAM_TURNS + k]: the neuron of turn k in agent a's last tick
INT_MAX = 2**31 - 1
# `normalneurons` in NetLogo's order (who numbers, as the source's setup creates them: labels 11, 12,
# 13, 21, 22, 31, 32, 23, 24), named as in services/brain/circuits/insect.toml.
SOURCE_NEURONS = ("BLACK", "RED", "GREEN", "PAIN", "REWARD", "MOVE", "ROTATE", "H1", "H2")


@njit(cache=True, inline="always")
def _twist(stream, a):
    """MT19937's next 624 words, in place (index back to 0)."""
    for k in range(N):
        y = (np.uint64(stream[a, k]) & np.uint64(0x80000000)) | (
            np.uint64(stream[a, (k + 1) % N]) & np.uint64(0x7FFFFFFF)
        )
        x = np.uint64(stream[a, (k + M) % N]) ^ (y >> np.uint64(1))
        if y & np.uint64(1):
            x ^= np.uint64(0x9908B0DF)
        stream[a, k] = np.uint32(x)
    stream[a, STREAM_INDEX] = 0


@njit(cache=True, inline="always")
def next_word(stream, a):
    """Agent a's next tempered 32-bit word (MersenneTwister.next_word), as an int64."""
    if stream[a, STREAM_INDEX] >= N:
        _twist(stream, a)
    i = stream[a, STREAM_INDEX]
    stream[a, STREAM_INDEX] = i + 1
    y = np.uint64(stream[a, i])
    y ^= y >> np.uint64(11)
    y ^= (y << np.uint64(7)) & np.uint64(0x9D2C5680)
    y ^= (y << np.uint64(15)) & np.uint64(0xEFC60000)
    y ^= y >> np.uint64(18)
    return np.int64(y & np.uint64(0xFFFFFFFF))


@njit(cache=True, inline="always")
def next_int(stream, a, n):
    """NetLogo's nextInt(n) from agent a's stream (MersenneTwister.next_int): 31 bits of a word,
    the top ones for a power of two, else a modulo with the uneven top rejected. n >= 1."""
    n = np.int64(n)
    if (n & -n) == n:
        return (n * (next_word(stream, a) >> 1)) >> 31
    while True:
        bits = next_word(stream, a) >> 1
        value = bits % n
        if bits - value + (n - 1) <= INT_MAX:
            return value


@njit(cache=True, inline="always")
def ask_draws(stream, a, n):
    """The draws of an ask over n agents whose commands draw nothing: nextInt(n) .. nextInt(2)."""
    for size in range(n, 1, -1):
        next_int(stream, a, size)


@njit(cache=True)
def next_ints(stream, a, bounds):
    """nextInt(bounds[k]) for each k in turn, from agent a's stream (for tests and checks)."""
    out = np.empty(bounds.shape[0], np.int64)
    for k in range(bounds.shape[0]):
        out[k] = next_int(stream, a, bounds[k])
    return out


def stream_row(words: list[int], index: int, neurons: int) -> np.ndarray:
    """One agent's row (uint32) from a generator's state (MersenneTwister.state())."""
    row = np.zeros(STREAM_TURNS + neurons, np.uint32)
    row[:N], row[STREAM_INDEX] = words, index
    return row


def setup_stream(netlogo_seed: int, neurons: int) -> np.ndarray:
    """The row of the stream as the SpikingLab source's setup leaves it after `random-seed N`."""
    return stream_row(*spikinglab_setup(netlogo_seed).stream.state(), neurons)


def source_order(circuit: Circuit) -> np.ndarray:
    """[neurons] uint64: the engine's neuron index of each normalneuron in NetLogo's order; ValueError
    for a circuit whose neurons are not the SpikingLab source's (its order is known for those only)."""
    if sorted(circuit.neuron_names) != sorted(SOURCE_NEURONS):
        raise ValueError(
            f"order netlogo-stream: the circuit's neurons must be the SpikingLab source's "
            f"({', '.join(SOURCE_NEURONS)}), got {', '.join(circuit.neuron_names)}"
        )
    return np.array([circuit.neuron_index(n) for n in SOURCE_NEURONS], np.uint64)
