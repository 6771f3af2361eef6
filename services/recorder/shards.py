"""World shards' state and maps (each a slice of one population) joined into the population's.

N world shards (`world --shard I/N --publish-state`) each send their slice's WorldMap and
WorldState batches, saying the slice's first agent (`first`), the population's size
(`population`) and N (`shards`); decoding has checked that the slice is shard I of N's.
`ShardJoin.take(message)` keeps them by slice and gives the whole population's messages as soon
as every slice has come: the map once every shard's has, the states for the ticks every shard has
sent (the shards' batches need not start at the same ticks), agents and arenas in population
order, so the recording is the one a whole world's run makes. A message of another population or
N, or that does not fit its shard's map, is refused (BusError) and nothing of it kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgspec
import numpy as np

from services.bus.schemas import Array, BusError, WorldMap, WorldState
from services.options import shard_slice
from services.vocabulary import EVENT_COLUMNS
from services.world.world import COLOURS

# a WorldState's arrays, each [T, agents, ...]: dtype, dimensions
STATE_ARRAYS = {
    "sensors": ("<f8", 3),
    "pos": ("<f8", 3),
    "heading": ("<f8", 2),
    "events": ("<i8", 3),
    "collisions": ("<i8", 2),
    "food": ("<i8", 2),
}
HELD_BYTES = 256 << 20  # the shards' ticks held waiting for the others, at most: beyond, the oldest are dropped


@dataclass
class Block:
    """Consecutive ticks of one shard's state from `tick`: its arrays and the patches it changed."""

    tick: int
    arrays: dict[str, np.ndarray]
    changes: np.ndarray  # [K, 5]: tick, arena (the population's), x index, y index, colour

    @property
    def end(self) -> int:
        return self.tick + len(self.arrays["pos"])

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays.values()) + self.changes.nbytes

    def cut(self, at: int) -> Block:
        """The ticks before `at`, taken off this block."""
        k = at - self.tick
        before = Block(self.tick, {n: a[:k] for n, a in self.arrays.items()}, self.changes[self.changes[:, 0] < at])
        self.tick, self.arrays = at, {n: a[k:] for n, a in self.arrays.items()}
        self.changes = self.changes[self.changes[:, 0] >= at]
        return before


class ShardJoin:
    """The shards of one run's population, and the ticks each has sent that the others have not yet."""

    def __init__(self):
        self.population, self.shards, self.run = 0, 0, ""
        self.slices: dict[int, int] = {}  # first agent -> agents (shard I of N's slice, decoding checked)
        self.maps: dict[int, WorldMap] = {}
        self.map_sent = False
        self.blocks: dict[int, list[Block]] = {}  # first agent -> ticks waiting for the other shards
        self.finals: set[int] = set()  # the shards whose final batch came
        self.sensor_names: tuple[str, ...] = ()
        self.joined_to = 0  # the tick after the last one joined

    def take(self, message: WorldMap | WorldState) -> list[WorldMap | WorldState]:
        """The population's messages that `message` (a shard's) completes, if any."""
        self.check(message)
        self.run, first = message.run, message.first
        if isinstance(message, WorldMap):
            self.maps[first] = message
            ready = self.complete and not self.map_sent and self.maps.keys() == self.slices.keys()
            return [self.joined_map()] if ready else []
        self.sensor_names = message.sensor_names
        arrays = {n: getattr(message, n).numpy(n, *STATE_ARRAYS[n]) for n in STATE_ARRAYS}
        changes = message.changes.numpy("changes", "<i8", 2) + np.array([0, first, 0, 0, 0])
        self.blocks.setdefault(first, []).append(Block(message.tick, arrays, changes))
        if message.final:
            self.finals.add(first)
        self.keep_within(HELD_BYTES)
        return self.joined_states()

    def check(self, message: WorldMap | WorldState) -> None:
        """BusError unless `message` is of a shard of the population and N the recording has."""
        first, population, shards = message.first, message.population, message.shards
        agents = message.grid.shape[0] if isinstance(message, WorldMap) else message.pos.shape[1]
        where = f"world shard of agents {first}..{first + agents - 1}"
        if self.population and (population, shards) != (self.population, self.shards):
            raise BusError(
                f"{where}: one of {shards} shards of {population} agents; the recording's are {self.shards} of "
                f"{self.population}"
            )
        if isinstance(message, WorldMap):
            self.check_map(message, where)
        elif first in self.finals:
            raise BusError(f"{where}: a state after its final batch")
        else:
            self.check_changes(message, agents, where)
        self.population, self.shards, self.slices[first] = population, shards, agents

    def check_map(self, message: WorldMap, where: str) -> None:
        kept = self.maps.get(message.first)
        if kept is not None and kept != message:
            raise BusError(f"{where}: a second map, not the one it began on")
        other = next(iter(self.maps.values()), message)
        if (other.grid.shape[1:], other.x_min, other.y_min) != (message.grid.shape[1:], message.x_min, message.y_min):
            raise BusError(
                f"{where}: a map of {list(message.grid.shape[1:])} patches from {message.x_min}, "
                f"{message.y_min}; another shard's is of {list(other.grid.shape[1:])} from {other.x_min}, {other.y_min}"
            )

    def check_changes(self, message: WorldState, agents: int, where: str) -> None:
        changes = message.changes.numpy("changes", "<i8", 2)
        size = next(iter(self.maps.values())).grid.shape[1:] if self.maps else (2**62, 2**62)
        if len(changes) and ((changes < 0) | (changes >= np.array([2**62, agents, *size, COLOURS]))).any():
            raise BusError(f"{where}: a map change outside its arenas")

    @property
    def complete(self) -> bool:
        """Whether every shard is known."""
        return bool(self.shards) and len(self.slices) == self.shards

    def silent(self) -> list[str]:
        """The shards ("I/N, agents a..b") that sent no state while another did: none of the
        population's ticks can be joined without them."""
        if not self.blocks:
            return []
        slices = [(i, shard_slice(self.population, (i, self.shards))) for i in range(1, self.shards + 1)]
        return [f"{i}/{self.shards} (agents {lo}..{hi - 1})" for i, (lo, hi) in slices if lo not in self.blocks]

    def joined_map(self) -> WorldMap:
        self.map_sent = True
        maps = [self.maps[f] for f in sorted(self.maps)]
        return WorldMap(
            tick=min(m.tick for m in maps),
            run=self.run,
            grid=Array.of(np.concatenate([m.grid.numpy("grid", "|u1", 3) for m in maps])),
            x_min=maps[0].x_min,
            y_min=maps[0].y_min,
        )

    def joined_states(self) -> list[WorldMap | WorldState]:
        """The ticks every shard has sent, as the population's states; ticks a shard's stream lost
        are dropped from the others' (the recorder says they are missing). The run's end once every
        shard's final batch came: ticks some shard sent beyond the others' end are dropped."""
        if not self.complete:
            return []
        out: list[WorldMap | WorldState] = []
        while all(self.blocks.get(f) for f in self.slices):
            start = max(self.blocks[f][0].tick for f in self.slices)
            for f in self.slices:
                self.drop_before(f, start)
            if all(self.blocks[f] and self.blocks[f][0].tick == start for f in self.slices):
                end = min(self.blocks[f][0].end for f in self.slices)
                out.append(self.joined_state(start, [self.take_until(f, end) for f in sorted(self.slices)]))
        if self.finals == self.slices.keys():
            if out:
                out[-1] = msgspec.structs.replace(out[-1], final=True)
            else:
                out.append(self.joined_state(self.joined_to, [], final=True))
            self.blocks.clear()
        return out

    def drop_before(self, first: int, tick: int) -> None:
        """A shard's ticks before `tick` (the others lost them) and its empty blocks, dropped."""
        blocks = self.blocks[first]
        while blocks and blocks[0].end <= tick:
            blocks.pop(0)
        if blocks and blocks[0].tick < tick:
            blocks[0].cut(tick)

    def take_until(self, first: int, tick: int) -> Block:
        """A shard's ticks before `tick`, from its first block."""
        blocks = self.blocks[first]
        return blocks.pop(0) if blocks[0].end == tick else blocks[0].cut(tick)

    def joined_state(self, tick: int, parts: list[Block], final: bool = False) -> WorldState:
        """The shards' parts of the same ticks (in population order) as one state of the population."""
        if parts:
            arrays = {n: np.concatenate([p.arrays[n] for p in parts], axis=1) for n in STATE_ARRAYS}
            changes = np.concatenate([p.changes for p in parts])
            changes = changes[np.argsort(changes[:, 0], kind="stable")]
        else:  # the run's end, no tick left
            columns = {"sensors": (len(self.sensor_names),), "pos": (2,), "events": (len(EVENT_COLUMNS),)}
            arrays = {n: np.zeros((0, self.population, *columns.get(n, ())), d) for n, (d, _) in STATE_ARRAYS.items()}
            changes = np.zeros((0, 5), np.int64)
        self.joined_to = tick + len(arrays["pos"])
        return WorldState.of(arrays, changes, tick=tick, run=self.run, sensor_names=self.sensor_names, final=final)

    def keep_within(self, limit: int) -> None:
        """The oldest ticks of the shard that holds the most dropped until what is held is within `limit`
        bytes (a shard whose state stopped coming must not grow the recorder without bound)."""
        held = {f: sum(b.nbytes for b in blocks) for f, blocks in self.blocks.items()}
        while sum(held.values()) > limit:
            f = max(held, key=held.__getitem__)
            held[f] -= self.blocks[f].pop(0).nbytes
