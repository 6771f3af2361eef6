"""Fuzzing the bus's decoders and the code that takes what they decode (Hypothesis).

Four kinds of payload, each thrown at decode() for every kind it may be expected as, and what
decodes, at the service code that takes it (the brain's answer and end check, the world's and the
gateway's motor handling, a world shard's check of the run it is named, the recorder):
  bytes:      arbitrary bytes
  byte:       byte-level mutants of a real message of the kind (bits flipped, bytes set, cut, inserted)
  structure:  a field's value replaced by any msgpack value, a field dropped or added, and the
              same with a string made invalid UTF-8
  any-shape:  well-formed messages of the kind with any shapes and values
Each payload ends as: rejected (by the decoder), refused (decoded, but the service refused it as
not fitting its run), taken, or an escape (any other exception: a crash in a service).
tests/bus/test_fuzz.py runs the same generators briefly; this prints, per key, how many payloads
were tried and how each ended. The generators are spikinglab/bench/mutants.py's, which need
hypothesis (the fuzz extra); the real messages they start from are here, without it (the soak bench
and the schema and fault tests use them too). The last line printed is JSON.
Run: `spikinglab bench fuzz [--examples N]`.
"""

from __future__ import annotations

import functools
import json
import logging
import traceback
import warnings
from collections import Counter

import msgspec
import numpy as np
import rerun as rr

from services.brain.circuit import load_circuit
from services.brain.node import BrainNode, layout
from services.bus import keys
from services.bus.schemas import (
    KINDS,
    Array,
    BrainLayout,
    BrainState,
    BusError,
    Control,
    Motor,
    RunTerms,
    Sensors,
    WorldMap,
    WorldState,
    decode,
)
from services.ev3_gateway.service import motor_actions
from services.options import Parser, at_least
from services.recorder.recorder import Recorder
from services.vocabulary import INSECT_ACTIONS, INSECT_SENSORS
from services.world import shards
from services.world.brains import actions_from

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
    RunTerms: keys.world_run("insect"),
}
# one real message of each kind, as the services send them for a run of 3 agents: all but the brain's
# state, which runs the engine (examples() has them all)
SENT = [
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
    RunTerms(
        tick=0,
        run="r1",
        agents=A,
        world_shards=2,
        brain_shards=1,
        seed=0,
        ticks=1000,
        preset="paper",
        learned_after=5000,
        training=True,
    ),
]


def serving_brain() -> BrainNode:
    """A brain that has answered the Sensors example: it serves run r1, for 3 agents."""
    node = BrainNode(CIRCUIT)
    node.answer(msgspec.structs.replace(SENT[0], tick=0))  # from the run's start: no word of joining late
    return node


@functools.cache
def examples() -> list:
    """SENT and a serving brain's state message: made on first use, not at import, which runs and
    may compile the engine (`bench fuzz` without hypothesis is refused before that)."""
    return [*SENT, serving_brain().state_message()]


def example(kind):
    return next(m for m in examples() if isinstance(m, kind))


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
        elif isinstance(message, RunTerms):  # a world shard's, of the lead's options: it joins only those
            attempt(lambda m: not shards.differences(example(RunTerms), m), message)
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


SOURCES = ("bytes", "byte", "structure", "any-shape")


def run(examples: int) -> tuple[dict, str | None]:
    """How the payloads of every source and kind ended, per key, and the first escape's traceback."""
    from .mutants import payloads

    services = Services()
    table: dict[str, Counter] = {}
    escapes: list[str] = []
    for kind in KINDS:
        for source in SOURCES:
            if source == "bytes" and kind is not Sensors:
                continue  # arbitrary bytes are no kind's: tried once, under "any key"
            counts = table.setdefault("any key" if source == "bytes" else KEY_OF[kind], Counter())
            throw_at(services, payloads(source, kind), examples, counts, escapes)
    return {key: dict(counts) for key, counts in table.items()}, escapes[0] if escapes else None


def throw_at(services: Services, strategy, examples: int, counts: Counter, escapes: list[str]) -> None:
    """`examples` payloads of `strategy` thrown at the services: how each ended into `counts`, the
    traceback of the first escape into `escapes`."""
    from hypothesis import given, settings

    from .mutants import HEALTH_CHECKS

    @settings(
        max_examples=examples, deadline=None, database=None, derandomize=True, suppress_health_check=HEALTH_CHECKS
    )
    @given(strategy)
    def throw(batch):
        for payload in batch:
            counts["tried"] += 1
            try:
                counts.update(services.outcomes(payload))
            except Exception:
                counts["escapes"] += 1
                escapes[:] = escapes or [traceback.format_exc()]  # the first one is shown

    throw()


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench fuzz", description=(__doc__ or "").splitlines()[0])
    p.add_argument(
        "--examples",
        type=at_least(1),
        default=2000,
        help="payloads per source and kind (default 2000; each is tried as every kind and any kind)",
    )
    args = p.parse_args(argv)
    try:
        import hypothesis  # noqa: F401  (the generators' library, which a plain install leaves out)
    except ModuleNotFoundError:
        p.exit(2, f"{p.prog}: needs hypothesis, which a plain install leaves out: pip install 'spikinglab[fuzz]'\n")
    warnings.simplefilter("ignore", RuntimeWarning)  # numpy's overflow notes on the extreme values thrown
    logging.getLogger("spikinglab").setLevel(logging.ERROR)  # the services' word on each payload they take
    table, escape = run(args.examples)
    print(f"{'key':36} {'payloads':>9} {'rejected':>9} {'refused':>8} {'taken':>7} {'escapes':>8}")
    for key, c in table.items():
        print(
            f"{key:36} {c.get('tried', 0):9,} {c.get('rejected', 0):9,} {c.get('refused', 0):8,} "
            f"{c.get('taken', 0):7,} {c.get('escapes', 0):8,}"
        )
    print(f"(each payload is decoded as every kind it may be expected as, and as any kind: {len(KINDS) + 1} outcomes)")
    if escape:
        print("first escape:\n" + escape)
    figures = {"examples": args.examples, "keys": table, "escapes": sum(c.get("escapes", 0) for c in table.values())}
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
