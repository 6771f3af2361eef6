"""Fuzzing the bus's decoders and the code that takes what they decode (Hypothesis).

Four kinds of payload, each thrown at decode() for every kind it may be expected as, and what
decodes, at the service code that takes it (the brain's answer and end check, the world's and the
gateway's motor handling, the recorder):
  bytes:      arbitrary bytes
  byte:       byte-level mutants of a real message of the kind (bits flipped, bytes set, cut, inserted)
  structure:  a field's value replaced by any msgpack value, a field dropped or added, and the
              same with a string made invalid UTF-8
  any-shape:  well-formed messages of the kind with any shapes and values
Each payload ends as: rejected (by the decoder), refused (decoded, but the service refused it as
not fitting its run), taken, or an escape (any other exception: a crash in a service).
tests/bus/test_fuzz.py runs the same generators briefly; this prints, per key, how many payloads
were tried and how each ended. Needs hypothesis (the test extras). The last line printed is JSON.
Run: `spikinglab bench fuzz [--examples N]`.
"""

from __future__ import annotations

import json
import logging
import traceback
import warnings
from collections import Counter

import msgspec
import numpy as np
import rerun as rr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from services.brain.circuit import load_circuit
from services.brain.service import BrainNode, layout
from services.bus import keys
from services.bus.schemas import (
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
from services.ev3_gateway.service import motor_actions
from services.options import Parser, at_least
from services.recorder.recorder import Recorder
from services.vocabulary import INSECT_ACTIONS, INSECT_SENSORS
from services.world.service import actions_from

raw_encode, raw_decode = msgspec.msgpack.Encoder().encode, msgspec.msgpack.Decoder().decode
CIRCUIT = load_circuit("insect")
A = 3
KEY_OF = {
    Sensors: keys.sensors("insect"),
    Motor: keys.motor("insect"),
    Control: keys.control("insect"),
    BrainState: keys.brain_state("insect"),
    BrainLayout: keys.brain_state("insect"),
    WorldState: keys.world_state("insect"),
    WorldMap: keys.world_map("insect"),
}
# one real message of each kind, as the services send them for a run of 3 agents
EXAMPLES = [
    Sensors(
        tick=7,
        names=INSECT_SENSORS,
        values=Array.of(np.array([[0.4, np.nan, np.nan, 1.0, np.nan]] * A)),
        run="r1",
        seed=4,
    ),
    Motor(tick=7, names=INSECT_ACTIONS, actions=Array.of(np.array([[1, 0]] * A, np.uint8)), run="r1"),
    Control(tick=40000, command="end", run="r1"),
    WorldState(
        tick=7,
        run="r1",
        sensor_names=("pain", "reward"),
        sensors=Array.of(np.full((50, A, 2), np.nan)),
        pos=Array.of(np.zeros((50, A, 2))),
        heading=Array.of(np.zeros((50, A))),
        events=Array.of(np.zeros((50, A, 4), np.int64)),
        collisions=Array.of(np.zeros((50, A), np.int64)),
        food=Array.of(np.zeros((50, A), np.int64)),
        changes=Array.of(np.array([[7, 1, 3, 4, 0]], np.int64)),
    ),
    WorldMap(tick=0, run="r1", grid=Array.of(np.zeros((A, 41, 60), np.uint8)), x_min=80, y_min=1),
    layout(CIRCUIT, 0, "r1"),
]


def serving_brain() -> BrainNode:
    """A brain that has answered the Sensors example: it serves run r1, for 3 agents."""
    node = BrainNode(CIRCUIT)
    node.answer(msgspec.structs.replace(EXAMPLES[0], tick=0))  # from the run's start: no word of joining late
    return node


EXAMPLES.append(serving_brain().state_message())


def example(kind):
    return next(m for m in EXAMPLES if isinstance(m, kind))


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


class Services:
    """The service code that takes decoded messages, set up as during a run of 3 agents: a brain
    serving run r1 (and a fresh one), the world's and the gateway's motor handling, a recorder,
    and for each state message a fresh recorder that joins it with a real one at a flush."""

    def __init__(self):
        self.serving = serving_brain()
        self.recorder = Recorder(rr.RecordingStream("spikinglab-fuzz"), detail=(0, 2), flush_every=1)
        for kind in (BrainLayout, BrainState, WorldMap, WorldState):
            self.recorder.on(example(kind))

    def take(self, message) -> str:
        """'taken' when some service that reads its key takes it, 'refused' when each refuses it (a
        BusError: it does not fit its run); any other exception escapes."""
        taken = []

        def attempt(step, *args):
            try:
                taken.append(step(*args) is not False)
            except BusError:
                taken.append(False)

        if isinstance(message, Sensors):
            attempt(BrainNode(CIRCUIT).answer, message)
            attempt(self.serving.answer, message)
        elif isinstance(message, Motor):
            attempt(lambda m: actions_from(m, A) is not None, message)  # the world's, for its 3 agents
            attempt(motor_actions, message, "r1")  # the gateway's, for its one robot
        elif isinstance(message, Control):
            attempt(self.serving.ends, message)
        else:
            attempt(self.recorder.on, message)
            self.recorder.flush()
            # a fresh recorder that holds the real message of that kind unflushed, as batches wait
            # between flushes, then takes this one: joining the two at the flush must not fail
            joined = Recorder(rr.RecordingStream("spikinglab-fuzz-joined"), detail=(0, 2), flush_every=2**62)
            for kind in dict.fromkeys((BrainLayout, WorldMap, type(message))):  # the map and layout, then one like it
                joined.on(example(kind))
            attempt(joined.on, message)
            joined.flush()
        return "taken" if any(taken) else "refused"

    def outcomes(self, payload: bytes) -> list[str]:
        """How the payload ends, for each kind it may be expected as and for any kind."""
        ends = []
        for expected in (*KINDS, KINDS):
            try:
                message = decode(payload, expected)
            except BusError:
                ends.append("rejected")
                continue
            ends.append(self.take(message))
        return ends


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


@st.composite
def messages(draw, kind=None):
    kind = kind or draw(st.sampled_from(KINDS))
    tick, T, A = draw(ticks), draw(st.integers(0, 3)), draw(st.sampled_from([3, 3, 1, 0, 2]))
    if kind is Sensors:
        sensor_names = draw(st.just(INSECT_SENSORS) | names)
        return Sensors(
            tick=tick,
            names=sensor_names,
            values=array(draw, "<f8", (A, len(sensor_names)), numbers),
            run=draw(runs),
            seed=draw(st.integers(0, 2**64 - 1) | st.integers(0, 9)),
        )
    if kind is Motor:
        action_names = draw(st.just(INSECT_ACTIONS) | names)
        return Motor(
            tick=tick,
            names=action_names,
            actions=array(draw, "|u1", (A, len(action_names)), st.integers(0, 255)),
            run=draw(runs),
        )
    if kind is BrainState:
        return BrainState(
            tick=tick,
            run=draw(runs),
            spiked=array(draw, "|u1", (T, A, NODES), st.integers(0, 1)),
            potentials=array(draw, "<f4", (T, A, NEURONS), st.floats(width=32)),
            weights=array(draw, "<f8", (A, SYNAPSES), numbers),
        )
    if kind is BrainLayout:
        return BrainLayout(
            tick=tick,
            run=draw(runs),
            circuit=draw(st.text(max_size=5)),
            nodes=draw(names | st.just(CIRCUIT.node_names)),
            neurons=draw(st.integers(0, 20) | i64),
            synapses=draw(names),
            plastic=tuple(draw(st.lists(i64, max_size=3))),
        )
    if kind is WorldState:
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
    if kind is WorldMap:
        return WorldMap(
            tick=tick,
            run=draw(runs),
            grid=array(draw, "|u1", (draw(st.integers(0, 3)), 41, 60), st.integers(0, 255)),
            x_min=draw(i64),
            y_min=draw(i64),
        )
    return kind(tick=tick, command=draw(st.text(max_size=5) | st.just("end")), run=draw(runs))


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


SOURCES = ("bytes", "byte", "structure", "any-shape")


def run(examples: int) -> tuple[dict, str | None]:
    services = Services()
    table: dict[str, Counter] = {}
    first_escape = None
    for kind in KINDS:
        for source in SOURCES:
            if source == "bytes" and kind is not Sensors:
                continue  # arbitrary bytes are no kind's: tried once, under "any key"
            counts = table.setdefault("any key" if source == "bytes" else KEY_OF[kind], Counter())

            @settings(
                max_examples=examples,
                deadline=None,
                database=None,
                derandomize=True,
                suppress_health_check=list(HealthCheck),
            )
            @given(payloads(source, kind))
            def throw(batch):
                nonlocal first_escape
                for payload in batch:
                    counts["tried"] += 1
                    try:
                        counts.update(services.outcomes(payload))
                    except Exception:
                        counts["escapes"] += 1
                        first_escape = first_escape or traceback.format_exc()

            throw()
    return {key: dict(counts) for key, counts in table.items()}, first_escape


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench fuzz", description=__doc__.split("\n")[0])
    p.add_argument(
        "--examples",
        type=at_least(1),
        default=2000,
        help="payloads per source and kind (default 2000; each is tried as every kind and any kind)",
    )
    args = p.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)  # numpy's overflow notes on the extreme values thrown
    logging.getLogger("spikinglab").setLevel(logging.ERROR)  # the services' word on each payload they take
    table, escape = run(args.examples)
    print(f"{'key':36} {'payloads':>9} {'rejected':>9} {'refused':>8} {'taken':>7} {'escapes':>8}")
    for key, c in table.items():
        print(
            f"{key:36} {c.get('tried', 0):9,} {c.get('rejected', 0):9,} {c.get('refused', 0):8,} "
            f"{c.get('taken', 0):7,} {c.get('escapes', 0):8,}"
        )
    print("(each payload is decoded as every kind it may be expected as, and as any kind: 8 outcomes)")
    if escape:
        print("first escape:\n" + escape)
    figures = {"examples": args.examples, "keys": table, "escapes": sum(c.get("escapes", 0) for c in table.values())}
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
