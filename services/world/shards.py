"""A sharded world (`world --shard I/N`): N world processes step one population, each its slice.

Shard 1 leads: it names the run (its id, on keys.world_run, until every other shard is on the
bus) with the options every shard must share (RunTerms; a shard whose own differ says which and
does not join), and ends it (Control "end" to the brains and the other shards) once every other
shard has finished its ticks (said by a liveliness token, world-<I>of<N>-done). Until it has
joined, each shard holds a token world-<I>of<N>-waiting-<session id>, and one that finds another
process as its shard, on the bus or waiting to join, stays off. Each shard writes
metrics-<I>of<N>.json to its --out; the lead merges those it finds in its own --out into
metrics.json (one summary where the shards share a folder). docs/shards.md.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import msgspec

from services.bus import keys
from services.bus.schemas import Control, RunTerms
from services.bus.transport import Bus, Inbox, Outbox, Presence

from .options import WorldOptions, file_digest, shown_option

log = logging.getLogger("spikinglab.world")
SAY_EVERY = 5.0  # seconds between "waiting for ..." lines
DUPLICATE_S = 2.0  # how long a starting shard watches for another process as that shard
UNDER_WAY_S = 10.0  # the lead on the bus this long naming no run: its run is under way (it names within ms)
INTERRUPTED_WAIT_S = 10.0  # a run cut short: how long the lead waits at most for the others to stop at its end

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


def others(bus: Bus, shard: tuple[int, int], done: bool = False) -> list:
    """The presences of the shards the lead waits for (`done`: their token of having finished)."""
    name = keys.world_done if done else keys.world_service
    return [bus.presence(name((i, shard[1]))) for i in range(2, shard[1] + 1)]


def terms(options: WorldOptions, run: str, world_shards: int, brain_shards: int) -> RunTerms:
    """The options of this shard that every shard of the run must share, with the run's id."""
    return RunTerms(
        tick=0,
        run=run,
        agents=options.agents,
        world_shards=world_shards,
        brain_shards=brain_shards,
        seed=options.seed,
        ticks=options.ticks,
        preset=options.preset,
        learned_after=options.learned_after,
        training=not options.no_training,
        netlogo_seed=options.netlogo_seed,
        map=file_digest(options.map),
        params=file_digest(options.params),
    )


OPTION = {  # a RunTerms field -> the option that sets it
    "agents": "--agents",
    "world_shards": "N of --shard I/N",
    "brain_shards": "--shards",
    "seed": "--seed",
    "ticks": "--ticks",
    "preset": "--preset",
    "learned_after": "--learned-after",
    "training": "--no-training (training)",
    "netlogo_seed": "--netlogo-seed",
    "map": "--map (its file's SHA-256)",
    "params": "--params (its file's SHA-256)",
}


class ShardsDisagree(ValueError):
    """This world shard's options differ from the lead's: the shards would not make one population."""


def differences(mine: RunTerms, lead: RunTerms) -> list[str]:
    """Each option on which this shard and the lead differ, as '--seed 7 here, 5 at world shard 1'."""
    return [
        f"{option} {shown_option(field, getattr(mine, field))} here, "
        f"{shown_option(field, getattr(lead, field))} at world shard 1"
        for field, option in OPTION.items()
        if getattr(mine, field) != getattr(lead, field)
    ]


class RunUnderWay(ValueError):
    """The lead runs a run that every shard joined already: this shard came too late to join it."""


class ShardTwice(ValueError):
    """Another process is this world shard already, on the bus or waiting to join it."""


def waiting_name(shard: tuple[int, int], session) -> str:
    """The name a world shard holds from its start until it has joined: world-<I>of<N>-waiting-<its
    session's id>, its own even beside a copy of it."""
    return f"world-{keys.shard_name(shard)}{keys.WAITING}{session.info.zid()}"


def join(session, group: str, shard: tuple[int, int], mine: RunTerms) -> tuple[Bus, RunTerms]:
    """This world shard on the bus, and the run's terms: as the lead named them, or for the lead
    itself `mine` (this shard's, its run still to be named: ""). ShardTwice where another process is
    this shard already (one started twice would step its slice twice, and a second lead would name a
    second run); ShardsDisagree where the lead's options differ. A shard other than the lead joins
    only once the lead has named the run, so until it has joined it holds a waiting token, which a
    copy started meanwhile finds as it would find the shard on the bus."""
    waiting = session.liveliness().declare_token(keys.alive(group, waiting_name(shard, session)))
    try:
        found = another_copy(session, group, shard)
        if found is not None:
            raise ShardTwice(
                f"world shard {shard[0]}/{shard[1]} is on the bus of group {group} already"
                f"{'' if found == keys.world_service(shard) else ', waiting to join'}: each shard is one process"
            )
        terms = follow(session, group, shard, mine) if shard[0] > 1 else mine
        return Bus(session, group, keys.world_service(shard)), terms
    finally:  # joined, its own name says it from here on
        waiting.undeclare()


def another_copy(session, group: str, shard: tuple[int, int]) -> str | None:
    """The name of another process that is this world shard (on the bus, or waiting to join), if one
    is alive within DUPLICATE_S: the tokens on the bus come to a new watch within moments, not at once
    (a liveliness query just after joining missed one in six). Each copy declares its waiting token
    before it watches, so that of two started together the later always finds the earlier (and the
    earlier the later, where its token comes within the earlier's DUPLICATE_S)."""
    joined, own = keys.world_service(shard), waiting_name(shard, session)
    copies = own.rpartition("-")[0]  # its waiting name but for the session's id

    def copy(name: str) -> bool:
        return name == joined or (name.rpartition("-")[0] == copies and name != own)

    watch = Presence(session, group, "*")
    try:
        return watch.first(copy, DUPLICATE_S)
    finally:
        watch.close()


def lead(bus: Bus, mine: RunTerms, run_id: str, shard: tuple[int, int]) -> None:
    """Name the run to the other shards until every one has joined the bus (it joins once it heard
    it), with this shard's terms (`mine`)."""
    named = msgspec.structs.replace(mine, run=run_id)
    outbox, waiting = bus.outbox(keys.world_run(bus.group)), others(bus, shard)
    said = time.monotonic()
    while not all(p.alive for p in waiting):
        outbox.put(named)
        if time.monotonic() - said > SAY_EVERY:
            missing = [p.service for p in waiting if not p.alive]
            log.info(
                "run %s: waiting for world shard(s) %s to join (one whose options differ says so and stays off)",
                named.run,
                ", ".join(missing),
            )
            said = time.monotonic()
        time.sleep(0.2)
    outbox.close()


def follow(session, group: str, shard: tuple[int, int], mine: RunTerms) -> RunTerms:
    """The run the lead shard names (before this shard joins the bus); ShardsDisagree where the
    lead's options differ from `mine`, RunUnderWay where the lead has been on the bus for
    UNDER_WAY_S naming none (it stops once every shard has joined: this one came too late)."""
    inbox, lead = Inbox(session, keys.world_run(group), RunTerms), Presence(session, group, "world")
    try:
        named = inbox.get(timeout=1.0)  # a lead on the bus names the run every 0.2 s
        lead_since, said = None, -SAY_EVERY
        while not isinstance(named, RunTerms):
            now = time.monotonic()
            lead_since = (lead_since or now) if lead.alive else None
            if lead_since is not None and now - lead_since > UNDER_WAY_S:
                raise RunUnderWay(
                    f"world shard {shard[0]}/{shard[1]}: world shard 1 is on the bus of group {group} but has named "
                    f"no run for {UNDER_WAY_S:.0f} s: its run is under way, every shard joined (a shard cannot join "
                    f"a run under way: start the run again, every shard)"
                )
            if now - said >= SAY_EVERY:
                log.info("world shard %d/%d: waiting for world shard 1/%d to name the run", *shard, shard[1])
                said = now
            named = inbox.get(timeout=1.0)
        found = differences(mine, named)
        if found:
            raise ShardsDisagree(
                f"world shard {shard[0]}/{shard[1]}: run {named.run} is not this shard's: " + "; ".join(found)
            )
        log.info("world shard %d/%d: run %s", *shard, named.run)
        return named
    finally:
        inbox.close()
        lead.close()


def end_run(bus: Bus, control: Outbox, shard: tuple[int, int], order: Control, interrupted: bool) -> list[str]:
    """The lead's (or a whole world's) end of the run: Control "end" once every other shard has
    finished its ticks; cut short, at once, then a moment for the others to stop at it too. The
    shards that left the bus before they finished (none when cut short: they stop early anyway)."""
    lost = []
    if shard[1] > 1 and not interrupted:
        lost = wait_for_others(bus, shard)
    control.put(order)
    if shard[1] > 1 and interrupted:
        wait_for_others(bus, shard, within=INTERRUPTED_WAIT_S)
    return lost


def wait_for_others(bus: Bus, shard: tuple[int, int], within: float | None = None) -> list[str]:
    """Until every other shard has finished its ticks (and written its metrics), or left the bus;
    `within` seconds at most. The shards that left without finishing."""
    done, there = others(bus, shard, done=True), others(bus, shard)
    since = said = time.monotonic()
    for t in there:  # known within a moment of subscribing, unless it has left
        t.wait(timeout=1.0)
    while not all(d.alive or not t.alive for d, t in zip(done, there)):
        if within is not None and time.monotonic() - since > within:
            break
        if time.monotonic() - said > SAY_EVERY:
            log.info("waiting for world shard(s) %s to finish", ", ".join(t.service for t in there if t.alive))
            said = time.monotonic()
        time.sleep(0.05)
    return [t.service for d, t in zip(done, there) if not d.alive and not t.alive]


class LeadsEnd:
    """Another shard's view of the lead's Control "end" of the run (asked every tick: a run cut
    short at the lead ends here too)."""

    def __init__(self, bus: Bus, run_id: str):
        self.control, self.run_id, self.came = bus.inbox(keys.control(bus.group), Control), run_id, False
        self.tick = -1  # the lead's tick at its end

    def __call__(self) -> bool:
        while not self.came and isinstance(order := self.control.get(timeout=0), Control):
            self.came, self.tick = order.run == self.run_id, order.tick
        return self.came


def finished(bus: Bus, shard: tuple[int, int], lead_ended: LeadsEnd, interrupted: bool) -> bool:
    """Another shard's end of the run (its metrics written): say it has finished, and wait for the
    lead to end the run (cut short here alone, too); False when the lead left the bus without it."""
    if interrupted and not lead_ended():
        log.warning(
            "world shard %d/%d stays on the bus until world shard 1 ends the run, so that the result has its "
            "insects (Ctrl-C again: it leaves now, and the run has no result)",
            *shard,
        )
    lead = bus.presence("world")
    token = bus.session.liveliness().declare_token(keys.alive(bus.group, keys.world_done(shard)))
    try:
        while not lead_ended() and lead.wait(timeout=1.0):  # (its token known within a moment of subscribing)
            time.sleep(0.02)
        last_word = time.monotonic() + 1.0  # an end sent as the lead left may come just after its token went
        while not lead_ended() and time.monotonic() < last_word:
            time.sleep(0.02)
        return lead_ended()
    finally:
        token.undeclare()


def merge_metrics(out: Path, shards: int, lost: list[str], run_id: str) -> None:
    """metrics.json of the whole population from the shards' metrics-<I>of<N>.json of run `run_id`
    in `out`; none where a shard was `lost`, or where its file is not there or is another run's (a
    shard that has not stopped yet, leaving an earlier run's file in the same folder)."""
    whole = out / "metrics.json"
    if lost:
        whole.unlink(missing_ok=True)
        return
    paths = [out / f"metrics-{keys.shard_name((i, shards))}.json" for i in range(1, shards + 1)]
    parts = [shard_metrics(p) for p in paths]
    said = [f"{p.name} {part}" for p, part in zip(paths, parts) if isinstance(part, str)]
    other = [p.name for p, part in zip(paths, parts) if isinstance(part, dict) and part.get("run") != run_id]
    said += [f"{', '.join(other)} of another run"] if other else []
    if said:
        whole.unlink(missing_ok=True)
        log.warning(
            "no metrics.json of run %s in %s: %s (a shard that has not stopped yet, or one with another --out)",
            run_id,
            out,
            "; ".join(said),
        )
        return
    whole.write_text(json.dumps(merged([part for part in parts if isinstance(part, dict)])))
    log.info("metrics of %d world shards merged into %s", shards, whole)


def shard_metrics(path: Path) -> dict | str:
    """A shard's metrics file, or what is wrong with it: "not there", or unreadable (one being
    written as an interrupted lead gives up waiting for its shard)."""
    try:
        part = json.loads(path.read_text())
    except FileNotFoundError:
        return "not there"
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        return f"unreadable ({e})"
    return part if isinstance(part, dict) else "unreadable (not a JSON object)"


def merged(parts: list[dict]) -> dict:
    """One run's metrics from its shards' (in shard order): per-agent lists joined, the run's pace
    that of the slowest shard."""
    whole = dict(parts[0])
    for name in PER_AGENT:
        whole[name] = [value for part in parts for value in part[name]]
    colours = parts[0]["collisions_by_colour"]
    whole["collisions_by_colour"] = {c: [v for part in parts for v in part["collisions_by_colour"][c]] for c in colours}
    whole["agents"] = sum(part["agents"] for part in parts)
    whole["ticks"] = min(part["ticks"] for part in parts)  # a run cut short: the shards stop where each is
    whole["shard_ticks"] = [part["ticks"] for part in parts]
    whole["partial"] = any(part["partial"] for part in parts)
    for name, slowest in (("elapsed_s", max), ("ticks_per_s", min), ("first_tick_s", max), ("steady_ticks_per_s", min)):
        if all(name in part for part in parts):
            whole[name] = slowest(part[name] for part in parts)
    whole["rejected_messages"] = rejected = {}
    for part in parts:
        for key, counts in part["rejected_messages"].items():
            for why, n in counts.items():
                rejected.setdefault(key, {})[why] = rejected.get(key, {}).get(why, 0) + n
    whole["brains_lost_at"] = sorted(t for part in parts for t in part.get("brains_lost_at", []))  # each shard's ticks
    whole["world_shards"] = len(parts)
    return whole
