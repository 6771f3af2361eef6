"""No payload, however malformed, gets past a decoder as anything but a BusError (Hypothesis):
arbitrary bytes, byte-level mutants of every schema's messages, and structure-aware mutants (a
field's value replaced by any msgpack value, a field dropped or added, strings made invalid UTF-8)."""

from __future__ import annotations

import msgspec
import numpy as np
import rerun as rr
from hypothesis import HealthCheck, given, settings, strategies as st

from spikinglab.brain.circuit import load_circuit
from spikinglab.brain.service import BrainNode, layout
from spikinglab.bus.schemas import (
    INSECT_ACTIONS,
    INSECT_SENSORS,
    KINDS,
    Array,
    BrainLayout,
    BrainState,
    BusError,
    Control,
    Motor,
    Sensors,
    WorldMap,
    WorldState,
    decode,
    encode,
)
from spikinglab.ev3_gateway.service import motor_actions
from spikinglab.recorder.recorder import Recorder
from spikinglab.world.service import actions_from

from .test_schemas import GOOD

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
raw_encode, raw_decode = msgspec.msgpack.Encoder().encode, msgspec.msgpack.Decoder().decode

# any msgpack value: what a peer could put in a field
values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(2**63), max_value=2**64 - 1) | st.floats()
    | st.text(max_size=20) | st.binary(max_size=64),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=5),
    max_leaves=20,
)


CIRCUIT = load_circuit("insect")


def consumers():
    """What each service does with a message it decoded: the brain answers Sensors (fresh, and
    already serving 3 agents), world and gateway take Motor actions, the recorder logs state."""
    serving = BrainNode(CIRCUIT)
    assert serving.answer(Sensors(tick=0, names=INSECT_SENSORS, values=Array.of(np.full((3, 5), np.nan)))) is not None
    recorder = Recorder(rr.RecordingStream("spikinglab-fuzz"), detail=(0, 2), flush_every=1)
    engine = serving.brain.engine
    recorder.on(layout(CIRCUIT, 0))
    recorder.on(serving.state_message())
    recorder.on(WorldMap(tick=0, grid=Array.of(np.zeros((3, 41, 60), np.uint8)), x_min=80, y_min=1))
    recorder.on(next(m for m in GOOD if isinstance(m, WorldState)))
    assert recorder.agents == 3 and recorder.spike_counts.shape == (3, engine.spiked.shape[1])
    return serving, recorder


SERVING, RECORDER = consumers()


def consume(message) -> None:
    if isinstance(message, Sensors):
        for node in (BrainNode(CIRCUIT), SERVING):
            try:
                node.answer(message)
            except BusError:  # refused: it does not fit the run
                pass
    elif isinstance(message, Motor):
        actions_from(message, 3)
        try:
            motor_actions(message, "")
        except BusError:
            pass
    elif isinstance(message, Control):
        try:
            SERVING.ends(message)
        except BusError:
            pass
    elif isinstance(message, (BrainLayout, BrainState, WorldMap, WorldState)):
        try:
            RECORDER.on(message)  # refuses, with a BusError, what does not fit the recording
        except BusError:
            pass
        RECORDER.flush()


def decodes_or_rejects(payload: bytes) -> None:
    """Every decoder (each kind expected, and any kind) either returns a message or raises BusError,
    and what it returns, its service takes without an exception."""
    for expected in (*KINDS, KINDS):
        try:
            message = decode(payload, expected)
        except BusError:
            continue
        consume(message)


@FUZZ
@given(st.binary(max_size=256))
def test_arbitrary_bytes(payload):
    decodes_or_rejects(payload)


@FUZZ
@given(st.sampled_from(GOOD), st.data())
def test_byte_mutants_of_every_schema(message, data):
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
    decodes_or_rejects(bytes(payload))


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


@FUZZ
@given(st.sampled_from(GOOD), st.data())
def test_structure_mutants_of_every_schema(message, data):
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
    decodes_or_rejects(payload)
    # the same, with its first string made invalid UTF-8 (msgpack str 0xA1..0xBF: one byte 0xFF)
    at = next((i for i, b in enumerate(payload) if 0xA1 <= b <= 0xBF), None)
    if at is not None and at + 1 < len(payload):
        decodes_or_rejects(payload[:at + 1] + b"\xff" + payload[at + 2:])


def test_the_nine_byte_message_that_killed_three_services():
    """A msgpack map whose `kind` is not valid UTF-8 (issue 12)."""
    payload = b"\x81\xa4kind\xa2\xff\xfe"
    decodes_or_rejects(payload)


# well-formed messages with any values, their shapes mostly consistent (so that they pass the
# schema's checks and reach the services' code) and mostly those of the run the consumers serve
ticks = st.integers(min_value=0, max_value=2**64 - 1) | st.integers(0, 60)
names = st.lists(st.sampled_from([*INSECT_SENSORS, "rotate", "move", "x"]), max_size=6).map(tuple)
numbers = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.0, -1.0, 1e300, 2.0**40, 0.2, 1.0])
i64 = st.integers(-(2**63), 2**63 - 1) | st.integers(-2, 70)
places = st.floats(-1e6, 1e6) | numbers
NODES, NEURONS, SYNAPSES = len(CIRCUIT.node_names), len(CIRCUIT.neuron_names), len(CIRCUIT.synapses)


def array(draw, dtype, shape, elements):
    shape = tuple(draw(st.sampled_from([n, 0, 1, 2, 5])) if draw(st.integers(0, 9)) == 0 else n for n in shape)
    flat = np.full(int(np.prod(shape)), draw(elements), dtype=dtype)  # one value, then a few others
    for _ in range(draw(st.integers(0, 5)) if len(flat) else 0):
        flat[draw(st.integers(0, len(flat) - 1))] = draw(elements)
    return Array.of(flat.reshape(shape))


@st.composite
def messages(draw):
    kind = draw(st.sampled_from(KINDS))
    tick, T, A = draw(ticks), draw(st.integers(0, 3)), draw(st.sampled_from([3, 3, 1, 0, 2]))
    if kind is Sensors:
        sensor_names = draw(st.just(INSECT_SENSORS) | names)
        return Sensors(tick=tick, names=sensor_names, values=array(draw, "<f8", (A, len(sensor_names)), numbers),
                       seed=draw(st.integers(0, 2**64 - 1) | st.integers(0, 9)))
    if kind is Motor:
        action_names = draw(st.just(INSECT_ACTIONS) | names)
        return Motor(tick=tick, names=action_names, actions=array(draw, "|u1", (A, len(action_names)),
                                                                  st.integers(0, 255)))
    if kind is BrainState:
        return BrainState(tick=tick, spiked=array(draw, "|u1", (T, A, NODES), st.integers(0, 1)),
                          potentials=array(draw, "<f4", (T, A, NEURONS), st.floats(width=32)),
                          weights=array(draw, "<f8", (A, SYNAPSES), numbers))
    if kind is BrainLayout:
        return BrainLayout(tick=tick, circuit=draw(st.text(max_size=5)), nodes=draw(names | st.just(CIRCUIT.node_names)),
                           neurons=draw(st.integers(0, 20) | i64), synapses=draw(names), plastic=tuple(draw(st.lists(i64, max_size=3))))
    if kind is WorldState:
        S, K = draw(st.integers(0, 5)), draw(st.integers(0, 3))
        return WorldState(tick=tick, sensor_names=draw(st.lists(st.sampled_from(INSECT_SENSORS), min_size=S,
                                                                max_size=S).map(tuple)),
                          sensors=array(draw, "<f8", (T, A, S), numbers), pos=array(draw, "<f8", (T, A, 2), places),
                          heading=array(draw, "<f8", (T, A), places), events=array(draw, "<i8", (T, A, 4), i64),
                          collisions=array(draw, "<i8", (T, A), i64), food=array(draw, "<i8", (T, A), i64),
                          changes=array(draw, "<i8", (K, 5), i64 | st.integers(0, 40)), final=draw(st.booleans()))
    if kind is WorldMap:
        return WorldMap(tick=tick, grid=array(draw, "|u1", (draw(st.integers(0, 3)), 41, 60), st.integers(0, 255)),
                        x_min=draw(i64), y_min=draw(i64))
    return kind(tick=tick, command=draw(st.text(max_size=5) | st.just("end")))


@FUZZ
@given(messages())
def test_well_formed_messages_of_any_shape_and_value(message):
    decodes_or_rejects(encode(message))
