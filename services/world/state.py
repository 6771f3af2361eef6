"""What the world publishes for the recorder: its ticks in WorldState batches (sensors, poses,
events, counters and the patches that changed), and the map the run starts on. A world shard's
say which slice of the population they hold (`first`, `population`: 0 for a whole world), so a
recorder joins the shards' into the population's."""

from __future__ import annotations

import numpy as np

from services.bus.batching import TickBatch, state_batch
from services.bus.schemas import Array, WorldMap, WorldState
from services.bus.transport import Outbox
from services.vocabulary import EVENT_COLUMNS

from .world import SENSORS, World


def world_map(world: World, run: str, population: int = 0, shards: int = 0) -> WorldMap:
    """The arenas as they are now, the first message a recorder gets of a run (`population`,
    `shards`: a world shard's, the whole population's size and the number of world shards)."""
    p = world.params
    return WorldMap(
        tick=world.tick,
        run=run,
        grid=Array.of(world.grid),
        x_min=p.x_min,
        y_min=p.y_min,
        first=int(world.numbers[0]) if population else 0,
        population=population,
        shards=shards,
    )


def keep_state(batch: TickBatch, changes: list, world: World, t: int, sensors: np.ndarray) -> None:
    """Tick t as the recorder sees it: its sensors, poses after the actions, its events and changes."""
    m = world.metrics
    batch.add(
        t,
        sensors=sensors,
        pos=world.pos,
        heading=world.heading,
        events=world.events,
        collisions=m.collisions,
        food=m.food,
    )
    for row in world.changes():
        changes.append((t, *row))


def state_message(
    batch: TickBatch, changes: list, final: bool, world: World, run: str, population: int = 0, shards: int = 0
) -> WorldState:
    """The ticks kept since the last message (none, when a run ends before its first tick)."""
    first, a = batch.take()
    if first is None:
        A = world.agents
        first, a = (
            world.tick,
            {
                "sensors": np.zeros((0, A, len(SENSORS))),
                "pos": np.zeros((0, A, 2)),
                "heading": np.zeros((0, A)),
                "events": np.zeros((0, A, len(EVENT_COLUMNS)), np.int64),
                "collisions": np.zeros((0, A), np.int64),
                "food": np.zeros((0, A), np.int64),
            },
        )
    message = WorldState.of(
        a,
        changes,
        tick=first,
        run=run,
        sensor_names=SENSORS,
        final=final,
        first=int(world.numbers[0]) if population else 0,
        population=population,
        shards=shards,
    )
    changes.clear()
    return message


class StateStream:
    """One run's ticks on their way to the recorder: kept tick by tick, sent a batch at a time
    (`population`, `shards`: a world shard's, the whole population's size and the number of shards)."""

    def __init__(self, outbox: Outbox, world: World, run: str, population: int = 0, shards: int = 0):
        self.outbox, self.world, self.run = outbox, world, run
        self.population, self.shards = population, shards
        self.batch, self.changes = TickBatch(state_batch(world.agents)), []

    def keep(self, t: int, sensors: np.ndarray) -> None:
        keep_state(self.batch, self.changes, self.world, t, sensors)

    @property
    def full(self) -> bool:
        return self.batch.full

    def send(self, final: bool = False) -> None:
        self.outbox.put(
            state_message(self.batch, self.changes, final, self.world, self.run, self.population, self.shards)
        )
