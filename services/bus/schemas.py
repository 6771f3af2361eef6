"""Message schemas of the bus: typed, versioned, decoded strictly.

Every message is a msgspec Struct tagged by `kind`, with the schema `version` and the `tick` it
belongs to. Arrays travel as bytes + dtype + shape (`Array`), never as lists. `decode` accepts a
message only if it is well formed, of the expected kind and version, and its arrays have the
dtypes and shapes the kind requires; otherwise it raises BusError with the reason, and nothing of
the message is used. Evolution: new fields get defaults; a change that old readers cannot take
bumps VERSION.
"""

from __future__ import annotations

import math
import re
import secrets
import struct
from typing import Annotated, cast

import msgspec
import numpy as np

from services.vocabulary import EVENT_COLUMNS

VERSION = 8  # 2: brain and world states come in batches of consecutive ticks; 3: no training switch on the bus;
# 4: sensors, motor and control name the run they belong to; 5: motor names the reading it answers, the states
# name their run; 6: sensors say when the world keeps a checkpoint; 7: a world shard's state and map say which
# slice of the population they hold; 8: the lead world shard names the run with RunTerms
_MAX_ELEMENTS = 1 << 26
_ITEMSIZE = {"<f8": 8, "<f4": 4, "<i8": 8, "|u1": 1}  # the dtypes messages carry


class BusError(ValueError):
    """A message was rejected; the text says why."""


class Array(msgspec.Struct, frozen=True):
    dtype: str
    shape: tuple[int, ...]
    data: bytes

    @classmethod
    def of(cls, a) -> Array:
        a = np.ascontiguousarray(a)
        if a.dtype.byteorder == ">":
            a = a.astype(a.dtype.newbyteorder("<"))
        return cls(a.dtype.str, tuple(a.shape), a.tobytes())

    @classmethod
    def view(cls, a: np.ndarray) -> Array:
        """As of(), but no copy: the message reads `a`'s memory when it is encoded, so `a` must hold
        the same values for as long as the message may be put. The lock-step sensors are put every
        tick: a 16,000-agent reading is 640 KB, and copying it (into fresh pages each tick) cost the
        world 200 us of its 4 ms tick."""
        if a.dtype.byteorder == ">" or not a.flags.c_contiguous:
            return cls.of(a)
        # msgspec encodes any buffer where a bytes field is expected; `data` is typed bytes for what
        # decode gives, so the view is cast to it.
        return cls(a.dtype.str, tuple(a.shape), cast(bytes, a.data.cast("B")))

    def check(self, field: str, dtype: str, ndim: int) -> None:
        """BusError unless dtype, number of dimensions, and byte length agree. Plain Python, no
        array made: on the lock-step path every numpy call costs ~5 us with cold caches."""
        if self.dtype != dtype:
            raise BusError(f"{field}: dtype {self.dtype!r}, expected {dtype!r}")
        if len(self.shape) != ndim or any(n < 0 for n in self.shape):
            raise BusError(f"{field}: shape {list(self.shape)}, expected {ndim} non-negative dimensions")
        count = math.prod(self.shape)
        if count > _MAX_ELEMENTS or count * _ITEMSIZE[dtype] != len(self.data):
            raise BusError(f"{field}: {len(self.data)} bytes do not hold shape {list(self.shape)} of {dtype}")

    def numpy(self, field: str, dtype: str, ndim: int) -> np.ndarray:
        """The array (read-only), checked as by check()."""
        self.check(field, dtype, ndim)
        return np.frombuffer(self.data, dtype=dtype).reshape(self.shape)


RunId = Annotated[str, msgspec.Meta(max_length=64)]  # chosen by the world (or gateway) when its run starts
RUN_ID = re.compile("[0-9a-f]{16}")  # what new_run_id() gives


def new_run_id() -> str:
    """A fresh run id, as the world and the gateway name each run they start."""
    return secrets.token_hex(8)


Seed = Annotated[int, msgspec.Meta(ge=0, lt=2**62)]  # a world's --seed
Tick = Annotated[int, msgspec.Meta(ge=0, lt=2**62)]  # a run's ticks; rerun and numpy take them as int64
Coordinate = Annotated[int, msgspec.Meta(ge=-(2**31), lt=2**31)]
AgentIndex = Annotated[int, msgspec.Meta(ge=0, lt=2**31)]
Population = Annotated[int, msgspec.Meta(ge=0, lt=2**31)]  # a world shard's population; 0: the world is whole
SENSED_MAX = 2.0**31  # a sensor value is a number of ticks for the input neuron to wait (int32 counters)


def _sensed_in_range(values: Array) -> bool:
    """Whether every sensed value (not NaN) is in [0, SENSED_MAX): in plain Python for a few
    agents' readings (a lock-step tick's, where numpy's calls cost more than the work), numpy for more."""
    if len(values.data) <= 8 * 64:
        return all(0 <= x < SENSED_MAX for x in struct.unpack(f"<{len(values.data) // 8}d", values.data) if x == x)
    sensed = values.numpy("values", "<f8", 2)
    return not ((sensed < 0) | (sensed >= SENSED_MAX)).any()  # NaN fails both: no mask (112 -> 15 us, A = 16000)


class Message(msgspec.Struct, tag_field="kind", frozen=True, kw_only=True):
    tick: Tick
    version: int = VERSION

    def check(self) -> None:
        """Kind-specific checks beyond the types; raise BusError."""


class Sensors(Message, tag="sensors", frozen=True, kw_only=True):
    """Sensor values of tick `tick` for A agents: values[a, k] for sensor names[k]; NaN: nothing."""

    names: tuple[str, ...]
    values: Array
    run: RunId = ""
    seed: Seed = 0  # the world's: the brain's netlogo order uses seed + a
    checkpoint: bool = False  # the world kept its state at the start of this tick: the brain keeps its own too
    first: AgentIndex = 0  # a shard's slice: the population's index of its first agent (netlogo order: seed + index)

    def check(self):
        self.values.check("values", "<f8", 2)
        agents, columns = self.values.shape
        if columns != len(self.names):
            raise BusError(f"values has {columns} columns for {len(self.names)} sensor names")
        if agents == 0:
            raise BusError("values for no agent")
        if not _sensed_in_range(self.values):
            raise BusError("values: a sensor value outside [0, 2**31) (NaN: nothing sensed)")


class Motor(Message, tag="motor", frozen=True, kw_only=True):
    """Which actions fired in tick `tick` of run `run`: actions[a, k] != 0 for action names[k]."""

    names: tuple[str, ...]
    actions: Array
    run: RunId = ""
    reading: Annotated[int, msgspec.Meta(ge=-1, lt=2**62)] = -1  # the tick of the reading answered; -1: not said
    first: AgentIndex = 0  # a shard's answer: the index of its first agent, as its sensors said

    def check(self):
        self.actions.check("actions", "|u1", 2)
        if self.actions.shape[1] != len(self.names):
            raise BusError(f"actions has {self.actions.shape[1]} columns for {len(self.names)} action names")


class Control(Message, tag="control", frozen=True, kw_only=True):
    """Run control. command: "end" (run `run` is over at `tick`: save and stop)."""

    command: str
    run: RunId = ""

    def check(self):
        if self.command != "end":
            raise BusError(f"unknown control command {self.command!r}")


class BrainState(Message, tag="brain_state", frozen=True, kw_only=True):
    """The brain over T consecutive ticks from `tick`: spikes [T, A, nodes] (u1), potentials
    [T, A, neurons] (f4), and the weights [A, synapses] (f8) after the batch's last tick. `final`:
    the last batch of the run."""

    run: RunId = ""  # the run it belongs to (a recorder keeps to the run of the first map or layout)
    spiked: Array
    potentials: Array
    weights: Array
    final: bool = False

    def check(self):
        spiked = self.spiked.numpy("spiked", "|u1", 3)
        if self.potentials.numpy("potentials", "<f4", 3).shape[:2] != spiked.shape[:2]:
            raise BusError(f"potentials cover {self.potentials.shape[:2]} ticks x agents, spiked {spiked.shape[:2]}")
        if self.weights.numpy("weights", "<f8", 2).shape[0] != spiked.shape[1]:
            raise BusError(f"weights have {self.weights.shape[0]} agents, spiked has {spiked.shape[1]}")


class BrainLayout(Message, tag="brain_layout", frozen=True, kw_only=True):
    """What the brain's arrays mean, sent once before its first state: node names (neurons first,
    then input neurons), the number of neurons, synapse labels "PRE->POST", the plastic ones."""

    run: RunId = ""  # the run it belongs to (a recorder keeps to the run of the first map or layout)
    circuit: str
    nodes: tuple[str, ...]
    neurons: int
    synapses: tuple[str, ...]
    plastic: tuple[int, ...]

    def check(self):
        if not 0 < self.neurons <= len(self.nodes):
            raise BusError(f"{self.neurons} neurons among {len(self.nodes)} nodes")
        if any(not 0 <= k < len(self.synapses) for k in self.plastic):
            raise BusError("a plastic synapse index is out of range")


class WorldState(Message, tag="world_state", frozen=True, kw_only=True):
    """The world over T consecutive ticks from `tick`: what each tick sensed, sensors [T, A, S]
    (NaN: nothing; the names as in Sensors), then after its actions pos [T, A, 2], heading [T, A],
    events [T, A, 4] (EVENT_COLUMNS), collisions [T, A], food [T, A]; and
    the patches that changed, changes [K, 5] (tick, arena, x index, y index, new colour).
    `final`: the last batch of the run."""

    run: RunId = ""  # the run it belongs to (a recorder keeps to the run of the first map or layout)
    sensor_names: tuple[str, ...]
    sensors: Array
    pos: Array
    heading: Array
    events: Array
    collisions: Array
    food: Array
    changes: Array
    final: bool = False
    first: AgentIndex = 0  # a world shard's: the population's index of its first agent (its arena 0)
    population: Population = 0  # a world shard's: the agents of the whole population; 0: this world is whole
    shards: Population = 0  # a world shard's: the number of world shards N (its slice is one of N)

    def check(self):
        self.changes.numpy("changes", "<i8", 2)
        shape = self.pos.numpy("pos", "<f8", 3).shape[:2]
        check_slice(self.first, shape[1], self.population, self.shards, "agents")
        if self.sensors.numpy("sensors", "<f8", 3).shape != (*shape, len(self.sensor_names)):
            raise BusError(
                f"sensors have shape {list(self.sensors.shape)} for {list(shape)} ticks x agents and "
                f"{len(self.sensor_names)} sensor names"
            )
        for name, arr, dtype, ndim in (
            ("heading", self.heading, "<f8", 2),
            ("events", self.events, "<i8", 3),
            ("collisions", self.collisions, "<i8", 2),
            ("food", self.food, "<i8", 2),
        ):
            if arr.numpy(name, dtype, ndim).shape[:2] != shape:
                raise BusError(f"{name} covers {arr.shape[:2]} ticks x agents, pos {shape}")
        if self.pos.shape[2] != 2 or self.changes.shape[1] != 5 or self.events.shape[2] != len(EVENT_COLUMNS):
            raise BusError("pos needs 2 columns, changes 5, events one per EVENT_COLUMNS")
        if not (
            np.isfinite(self.pos.numpy("pos", "<f8", 3)).all()
            and np.isfinite(self.heading.numpy("heading", "<f8", 2)).all()
        ):
            raise BusError("pos and heading must be finite")

    @classmethod
    def of(
        cls,
        arrays,
        changes,
        *,
        tick: int,
        run: str,
        sensor_names,
        final: bool = False,
        first: int = 0,
        population: int = 0,
        shards: int = 0,
    ) -> WorldState:
        """From numpy arrays: `arrays` by name (sensors, pos, heading, events, collisions, food),
        `changes` the changed patches' rows of 5 (any sequence)."""
        a = {n: Array.of(arrays[n]) for n in ("sensors", "pos", "heading", "events", "collisions", "food")}
        return cls(
            tick=tick,
            run=run,
            sensor_names=tuple(sensor_names),
            sensors=a["sensors"],
            pos=a["pos"],
            heading=a["heading"],
            events=a["events"],
            collisions=a["collisions"],
            food=a["food"],
            changes=Array.of(np.array(changes, np.int64).reshape(-1, 5)),
            final=final,
            first=first,
            population=population,
            shards=shards,
        )


class WorldMap(Message, tag="world_map", frozen=True, kw_only=True):
    """The arenas: grid [arenas, width, height] of colours (EMPTY, BLACK, RED, GREEN), patch (0, 0)
    at (x_min, y_min)."""

    run: RunId = ""  # the run it belongs to (a recorder keeps to the run of the first map or layout)
    grid: Array
    x_min: Coordinate
    y_min: Coordinate
    first: AgentIndex = 0  # a world shard's: the population's index of its first agent, whose arena is its 0
    population: Population = 0  # a world shard's: the agents (and arenas) of the whole population; 0: whole
    shards: Population = 0  # a world shard's: the number of world shards N (its slice is one of N)

    def check(self):
        if 0 in self.grid.numpy("grid", "|u1", 3).shape:
            raise BusError(f"grid of shape {list(self.grid.shape)}: no arena")
        check_slice(self.first, self.grid.shape[0], self.population, self.shards, "arenas")


def check_slice(first: int, agents: int, population: int, shards: int, what: str) -> None:
    """BusError unless `agents` from `first` are a world shard's slice: shard I of `shards` of the
    population has agents P(I-1)//N .. PI//N - 1 (services.options.shard_slice). A whole world says
    first 0, population 0, shards 0."""
    if population == 0:
        if first or shards:
            raise BusError(f"first agent {first}, {shards} shards in a whole world (population 0)")
        return
    if first + agents > population:
        raise BusError(f"{what} {first}..{first + agents - 1} outside the population of {population}")
    if not 1 <= shards <= population:
        raise BusError(f"{shards} world shards of a population of {population}")
    i = -(-first * shards // population)  # the shard whose slice starts at `first`, if one does
    if population * i // shards != first or population * (i + 1) // shards != first + agents:
        raise BusError(
            f"{what} {first}..{first + agents - 1}: not one of {shards} world shards' slices of {population}"
        )


Preset = Annotated[str, msgspec.Meta(max_length=64)]  # a world preset's name
ShardCount = Annotated[int, msgspec.Meta(ge=1, lt=2**31)]
Digest = Annotated[str, msgspec.Meta(pattern="^([0-9a-f]{64})?$")]  # a file's SHA-256, "" for no file
NetLogoSeed = Annotated[int, msgspec.Meta(ge=-(2**31), lt=2**31)]  # NetLogo's random-seed: a Java int


class RunTerms(Message, tag="run_terms", frozen=True, kw_only=True):
    """World shard 1's name for the run (`run`), sent to the other world shards with the options
    that make one population of their slices: each compares its own before it joins."""

    run: RunId
    agents: Population
    world_shards: ShardCount
    brain_shards: ShardCount
    seed: Seed
    ticks: Tick
    preset: Preset
    learned_after: Tick
    training: bool
    netlogo_seed: NetLogoSeed | None = None
    map: Digest = ""  # the --map file's
    params: Digest = ""  # the --params file's


def _undecoded(e: Exception) -> BusError:
    """The reason a payload did not decode as any message."""
    if isinstance(e, msgspec.ValidationError):
        return BusError(f"invalid message: {e}")
    if isinstance(e, msgspec.DecodeError):
        return BusError(f"not a message: {e}")
    return BusError(f"not a message: {type(e).__name__}: {e}")  # msgspec lets others through, e.g. UnicodeDecodeError


KINDS = (Sensors, Motor, Control, BrainState, BrainLayout, WorldState, WorldMap, RunTerms)
_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(
    Sensors | Motor | Control | BrainState | BrainLayout | WorldState | WorldMap | RunTerms
)


def encode(message: Message) -> bytes:
    return _encoder.encode(message)


class _Versioned(msgspec.Struct):
    """A message's version field alone (every other field ignored)."""

    version: int = VERSION


_version_decoder = msgspec.msgpack.Decoder(_Versioned)


def _other_version(payload: bytes) -> BusError | None:
    """The version mismatch of a payload that did not decode, if it names another version: a
    message of another version rarely has this one's fields, and its version is the news."""
    try:
        version = _version_decoder.decode(payload).version
    except Exception:  # no map with an int version: the decoder's own reason stands
        return None
    return BusError(f"schema version {version}, this program speaks {VERSION}") if version != VERSION else None


def decode(payload: bytes, expected: type[Message] | tuple[type[Message], ...] = KINDS) -> Message:
    """The message in `payload`, or BusError naming what is wrong."""
    try:
        message = _decoder.decode(payload)
    except Exception as e:
        raise _other_version(payload) or _undecoded(e) from None
    if message.version != VERSION:
        raise BusError(f"schema version {message.version}, this program speaks {VERSION}")
    if not isinstance(message, expected):
        names = expected.__name__ if isinstance(expected, type) else "/".join(t.__name__ for t in expected)
        raise BusError(f"a {type(message).__name__} message where {names} was expected")
    try:
        message.check()
    except BusError:
        raise
    except Exception as e:  # a check that trips over a value it did not foresee still rejects
        raise BusError(f"invalid {type(message).__name__}: {type(e).__name__}: {e}") from None
    return message
