"""Hypothesis strategies for payloads that a peer could put on the bus: arbitrary bytes, byte-level
and structural mutants of a real message of each kind, and well-formed messages of any shape and
value (the sources of `spikinglab bench fuzz` and tests/bus/test_fuzz.py). Needs hypothesis (the
fuzz extra)."""

from __future__ import annotations

import msgspec
import numpy as np
from hypothesis import HealthCheck
from hypothesis import strategies as st

from services.bus.schemas import (
    KINDS,
    Array,
    BrainLayout,
    BrainState,
    Control,
    Motor,
    RunTerms,
    Sensors,
    WorldMap,
    WorldState,
    encode,
)
from services.vocabulary import INSECT_ACTIONS, INSECT_SENSORS

from .fuzz import CIRCUIT, example

raw_encode, raw_decode = msgspec.msgpack.Encoder().encode, msgspec.msgpack.Decoder().decode
# what the big messages trip and is no fault of the code under test: slow and large examples
HEALTH_CHECKS = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example]

# any msgpack value: what a peer could put in a field
values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats()
    | st.text(max_size=20)
    | st.binary(max_size=64),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=5),
    max_leaves=20,
)


def byte_mutant(data, message) -> bytes:
    payload = bytearray(encode(message))
    for _ in range(data.draw(st.integers(1, 4))):
        where = data.draw(st.integers(0, len(payload) - 1))
        how = data.draw(st.sampled_from(["flip", "set", "cut", "insert"]))
        if how == "flip":
            payload[where] ^= 1 << data.draw(st.integers(0, 7))
        elif how == "set":
            payload[where] = data.draw(st.sampled_from([0x00, 0x7F, 0x80, 0xC0, 0xC1, 0xFF, 0xA1, 0xD9, 0xDC, 0xDF]))
        elif how == "cut":
            del payload[where:]
            if not payload:
                payload.append(0x90)
        else:
            payload[where:where] = data.draw(st.binary(min_size=1, max_size=4))
    return bytes(payload)


def paths(tree, prefix=()):
    """Every place in a decoded message: a key of a map or an index of a list."""
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield (*prefix, k)
            yield from paths(v, (*prefix, k))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            yield (*prefix, i)
            yield from paths(v, (*prefix, i))


def structure_mutants(data, message) -> list[bytes]:
    """A mutant of the message's structure, and the same with its first string made invalid UTF-8."""
    tree = raw_decode(encode(message))
    for _ in range(data.draw(st.integers(1, 3))):
        place = data.draw(st.sampled_from(list(paths(tree))))
        parent = tree
        for step in place[:-1]:
            parent = parent[step]
        how = data.draw(st.sampled_from(["replace", "drop", "add"]))
        if how == "replace":
            parent[place[-1]] = data.draw(values)
        elif how == "drop" and isinstance(parent, dict):
            del parent[place[-1]]
        elif isinstance(parent, dict):
            parent[data.draw(st.text(max_size=8))] = data.draw(values)
        if not isinstance(tree, dict) or not list(paths(tree)):
            break
    payload = raw_encode(tree)
    at = next((i for i, b in enumerate(payload) if 0xA1 <= b <= 0xBF), None)  # a msgpack str of 1..31 bytes
    if at is None or at + 1 >= len(payload):
        return [payload]
    return [payload, payload[: at + 1] + b"\xff" + payload[at + 2 :]]


# well-formed messages with any values, their shapes mostly consistent (so that they pass the
# schema's checks and reach the services' code) and mostly those of the run the consumers serve
ticks = st.integers(min_value=0, max_value=2**64 - 1) | st.integers(0, 60)
names = st.lists(st.sampled_from([*INSECT_SENSORS, "rotate", "move", "x"]), max_size=6).map(tuple)
numbers = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.0, -1.0, 1e300, 2.0**40, 0.2, 1.0])
i64 = st.integers(-(2**63), 2**63 - 1) | st.integers(-2, 70)
places = st.floats(-1e6, 1e6) | numbers
runs = st.sampled_from(["r1", "r1", "", "r2"]) | st.text(max_size=70)
NODES, NEURONS, SYNAPSES = len(CIRCUIT.node_names), len(CIRCUIT.neuron_names), len(CIRCUIT.synapses)


def array(draw, dtype, shape, elements):
    shape = tuple(draw(st.sampled_from([n, 0, 1, 2, 5])) if draw(st.integers(0, 9)) == 0 else n for n in shape)
    flat = np.full(int(np.prod(shape)), draw(elements), dtype=dtype)  # one value, then a few others
    for _ in range(draw(st.integers(0, 5)) if len(flat) else 0):
        flat[draw(st.integers(0, len(flat) - 1))] = draw(elements)
    return Array.of(flat.reshape(shape))


def sensors(draw, tick, T, A):
    sensor_names = draw(st.just(INSECT_SENSORS) | names)
    return Sensors(
        tick=tick,
        names=sensor_names,
        values=array(draw, "<f8", (A, len(sensor_names)), numbers),
        run=draw(runs),
        seed=draw(st.integers(0, 2**64 - 1) | st.integers(0, 9)),
    )


def motor(draw, tick, T, A):
    action_names = draw(st.just(INSECT_ACTIONS) | names)
    return Motor(
        tick=tick,
        names=action_names,
        actions=array(draw, "|u1", (A, len(action_names)), st.integers(0, 255)),
        run=draw(runs),
    )


def brain_state(draw, tick, T, A):
    return BrainState(
        tick=tick,
        run=draw(runs),
        spiked=array(draw, "|u1", (T, A, NODES), st.integers(0, 1)),
        potentials=array(draw, "<f4", (T, A, NEURONS), st.floats(width=32)),
        weights=array(draw, "<f8", (A, SYNAPSES), numbers),
    )


def brain_layout(draw, tick, T, A):
    return BrainLayout(
        tick=tick,
        run=draw(runs),
        circuit=draw(st.text(max_size=5)),
        nodes=draw(names | st.just(CIRCUIT.node_names)),
        neurons=draw(st.integers(0, 20) | i64),
        synapses=draw(names),
        plastic=tuple(draw(st.lists(i64, max_size=3))),
    )


def world_state(draw, tick, T, A):
    S, K = draw(st.integers(0, 5)), draw(st.integers(0, 3))
    return WorldState(
        tick=tick,
        run=draw(runs),
        sensor_names=tuple(draw(st.lists(st.sampled_from(INSECT_SENSORS), min_size=S, max_size=S))),
        sensors=array(draw, "<f8", (T, A, S), numbers),
        pos=array(draw, "<f8", (T, A, 2), places),
        heading=array(draw, "<f8", (T, A), places),
        events=array(draw, "<i8", (T, A, 4), i64),
        collisions=array(draw, "<i8", (T, A), i64),
        food=array(draw, "<i8", (T, A), i64),
        changes=array(draw, "<i8", (K, 5), i64 | st.integers(0, 40)),
        final=draw(st.booleans()),
    )


def world_map(draw, tick, T, A):
    return WorldMap(
        tick=tick,
        run=draw(runs),
        grid=array(draw, "|u1", (draw(st.integers(0, 3)), 41, 60), st.integers(0, 255)),
        x_min=draw(i64),
        y_min=draw(i64),
    )


def control(draw, tick, T, A):
    return Control(tick=tick, command=draw(st.text(max_size=5) | st.just("end")), run=draw(runs))


def run_terms(draw, tick, T, A):
    counts, digests = st.integers(0, 4) | i64, st.sampled_from(["", "0" * 64, "f" * 64]) | st.text(max_size=70)
    return RunTerms(
        tick=tick,
        run=draw(runs),
        agents=draw(st.just(A) | counts),
        world_shards=draw(counts),
        brain_shards=draw(counts),
        seed=draw(st.integers(0, 2**64 - 1) | st.integers(0, 9)),
        ticks=draw(ticks),
        preset=draw(st.sampled_from(["paper", "netlogo"]) | st.text(max_size=70)),
        learned_after=draw(ticks),
        training=draw(st.booleans()),
        netlogo_seed=draw(st.none() | i64),
        map=draw(digests),
        params=draw(digests),
    )


BUILDERS = {
    Sensors: sensors,
    Motor: motor,
    BrainState: brain_state,
    BrainLayout: brain_layout,
    WorldState: world_state,
    WorldMap: world_map,
    Control: control,
    RunTerms: run_terms,
}


@st.composite
def messages(draw, kind=None):
    """A well-formed message of `kind` (else of any kind): T ticks of A agents, any values."""
    kind = kind or draw(st.sampled_from(KINDS))
    tick, T, A = draw(ticks), draw(st.integers(0, 3)), draw(st.sampled_from([3, 3, 1, 0, 2]))
    return BUILDERS[kind](draw, tick, T, A)


def payloads(source: str, kind) -> st.SearchStrategy:
    """Payloads (lists of bytes) of one source for one kind."""
    real = example(kind)
    if source == "bytes":
        return st.binary(max_size=256).map(lambda b: [b])
    if source == "byte":
        return st.composite(lambda draw: [byte_mutant(Drawer(draw), real)])()
    if source == "structure":
        return st.composite(lambda draw: structure_mutants(Drawer(draw), real))()
    return messages(kind).map(lambda m: [encode(m)])


class Drawer:
    """A composite strategy's draw, with the .draw() of st.data() that the mutators call."""

    def __init__(self, draw):
        self.draw = draw
