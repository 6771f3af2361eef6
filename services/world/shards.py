"""A sharded world (`world --shard I/N`): N world processes step one population, each its slice.

Shard 1 leads: it names the run (its id, on keys.world_run, until every other shard is on the
bus), and ends it (Control "end" to the brains and the other shards) once every other shard has
finished its ticks (said by a liveliness token, world-<I>of<N>-done). Each shard writes
metrics-<I>of<N>.json to its --out; the lead merges those it finds in its own --out into
metrics.json (one summary where the shards share a folder). docs/shards.md.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

from services.bus import keys
from services.bus.schemas import Array, Control, WorldMap
from services.bus.transport import Bus, Inbox, Outbox

from .world import World

log = logging.getLogger("spikinglab.world")
SAY_EVERY = 5.0  # seconds between "waiting for ..." lines
INTERRUPTED_WAIT_S = 3.0  # a run cut short: how long the lead waits for the others to stop at its end

# per-agent lists of metrics.json, in the population's order when the shards' are joined
PER_AGENT = (
    "collisions_per_1000_ticks",
    "collisions",
    "food",
    "distance",
    "resets",
    "ticks_since_last_collision",
    "learning_time",
)


def service_name(shard: tuple[int, int]) -> str:
    """The name a world is alive under: "world" (a whole world, or the lead shard), or "world-2of3"."""
    return "world" if shard[0] == 1 else f"world-{keys.shard_name(shard)}"


def others(bus: Bus, shard: tuple[int, int], done: bool = False) -> list:
    """The presences of the shards the lead waits for (`done`: their token of having finished)."""
    return [bus.presence(service_name((i, shard[1])) + ("-done" if done else "")) for i in range(2, shard[1] + 1)]


def lead(bus: Bus, world: World, run_id: str, shard: tuple[int, int]) -> None:
    """Name the run to the other shards until every one has joined the bus (it joins once it heard it)."""
    outbox, waiting = bus.outbox(keys.world_run(bus.group)), others(bus, shard)
    named = WorldMap(tick=world.tick, run=run_id, grid=Array.of(world.grid[:1]), x_min=0, y_min=0)
    said = time.monotonic()
    while not all(p.alive for p in waiting):
        outbox.put(named)
        if time.monotonic() - said > SAY_EVERY:
            missing = [p.service for p in waiting if not p.alive]
            log.info("run %s: waiting for world shard(s) %s to join", run_id, ", ".join(missing))
            said = time.monotonic()
        time.sleep(0.2)
    outbox.close()


def follow(session, group: str, shard: tuple[int, int]) -> str:
    """The run the lead shard names (before this shard joins the bus)."""
    inbox = Inbox(session, keys.world_run(group), WorldMap)
    try:
        while not isinstance(named := inbox.get(timeout=SAY_EVERY), WorldMap):
            log.info("world shard %d/%d: waiting for world shard 1/%d to name the run", *shard, shard[1])
        log.info("world shard %d/%d: run %s", *shard, named.run)
        return named.run
    finally:
        inbox.close()


def end_run(bus: Bus, control: Outbox, shard: tuple[int, int], order: Control, interrupted: bool) -> None:
    """The lead's (or a whole world's) end of the run: Control "end" once every other shard has
    finished its ticks; cut short, at once, then a moment for the others to stop at it too."""
    if shard[1] > 1 and not interrupted:
        wait_for_others(bus, shard)
    control.put(order)
    if shard[1] > 1 and interrupted:
        wait_for_others(bus, shard, within=INTERRUPTED_WAIT_S)


def wait_for_others(bus: Bus, shard: tuple[int, int], within: float | None = None) -> None:
    """Until every other shard has finished its ticks (and written its metrics), or left the bus;
    `within` seconds at most."""
    done, there, said = others(bus, shard, done=True), others(bus, shard), time.monotonic()
    for t in there:  # known within a moment of subscribing, unless it has left
        t.wait(timeout=1.0)
    while not all(d.alive or not t.alive for d, t in zip(done, there)):
        if within is not None and time.monotonic() - said > within:
            return
        if within is None and time.monotonic() - said > SAY_EVERY:
            log.info("waiting for world shard(s) %s to finish", ", ".join(t.service for t in there if t.alive))
            said = time.monotonic()
        time.sleep(0.05)


class LeadsEnd:
    """Another shard's view of the lead's Control "end" of the run (asked every tick: a run cut
    short at the lead ends here too)."""

    def __init__(self, bus: Bus, run_id: str):
        self.control, self.run_id, self.came = bus.inbox(keys.control(bus.group), Control), run_id, False

    def __call__(self) -> bool:
        while not self.came and isinstance(order := self.control.get(timeout=0), Control):
            self.came = order.run == self.run_id
        return self.came


def finished(bus: Bus, shard: tuple[int, int], lead_ended: LeadsEnd) -> None:
    """Another shard's end of the run: say it has finished, and wait for the lead to end the run
    (or to leave the bus)."""
    lead = bus.presence("world")
    token = bus.session.liveliness().declare_token(keys.alive(bus.group, service_name(shard) + "-done"))
    try:
        while not lead_ended() and lead.wait(timeout=1.0):  # (its token known within a moment of subscribing)
            time.sleep(0.02)
    finally:
        token.undeclare()


def merge_metrics(out: Path, shards: int) -> None:
    """metrics.json of the whole population from the shards' metrics-<I>of<N>.json in `out`."""
    paths = [out / f"metrics-{keys.shard_name((i, shards))}.json" for i in range(1, shards + 1)]
    missing = [p.name for p in paths if not p.exists()]
    if missing:
        log.warning("no metrics.json: %s not in %s (each shard writes its own to its --out)", ", ".join(missing), out)
        return
    (out / "metrics.json").write_text(json.dumps(merged([json.loads(p.read_text()) for p in paths])))
    log.info("metrics of %d world shards merged into %s", shards, out / "metrics.json")


def merged(parts: list[dict]) -> dict:
    """One run's metrics from its shards' (in shard order): per-agent lists joined, the run's pace
    that of the slowest shard."""
    whole = dict(parts[0])
    for name in PER_AGENT:
        whole[name] = [value for part in parts for value in part[name]]
    colours = parts[0]["collisions_by_colour"]
    whole["collisions_by_colour"] = {c: [v for part in parts for v in part["collisions_by_colour"][c]] for c in colours}
    whole["agents"] = sum(part["agents"] for part in parts)
    whole["ticks"] = min(part["ticks"] for part in parts)
    whole["partial"] = any(part["partial"] for part in parts)
    for name, slowest in (("elapsed_s", max), ("ticks_per_s", min), ("first_tick_s", max), ("steady_ticks_per_s", min)):
        if all(name in part for part in parts):
            whole[name] = slowest(part[name] for part in parts)
    whole["rejected_messages"] = rejected = {}
    for part in parts:
        for key, counts in part["rejected_messages"].items():
            for why, n in counts.items():
                rejected.setdefault(key, {})[why] = rejected.get(key, {}).get(why, 0) + n
    whole["world_shards"] = len(parts)
    return whole
