"""The world service: `spikinglab world` / `python -m services.world`.

Reads:  spikinglab/<group>/motor (Motor), liveliness spikinglab/<group>/alive/brain
Writes: spikinglab/<group>/sensors (Sensors), .../control (Control "end"), .../world/state and
        .../world/map (for the recorder), liveliness spikinglab/<group>/alive/world

Lock-step: the world publishes the sensors of tick t, waits for the brain's Motor of tick t,
applies it and advances. Without a brain it waits and says so; it never invents a tick. When no
answer comes within a second the sensors are sent again (the brain answers a repeated tick from
its cache), so a brain that was restarted picks the run up where it stopped.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from services.bus import keys
from services.bus.config import BusConfig, add_bus_args
from services.bus.schemas import Control, RunTerms, Sensors, new_run_id
from services.bus.transport import Bus, wait_for_subscriber
from services.interrupts import ctrl_c_in_waits
from services.options import Parser, at_least, output_file, output_folder
from services.options import shard as shard_of_n
from services.runtime import service_main

from . import checkpoint, shards
from .brains import Brains
from .checkpoint import CHECKPOINT, PENDING, resume
from .options import WorldOptions, add_world_args, file_digest, shards_fit, world_from
from .results import Progress, Trajectory, metrics_of, outcome
from .state import StateStream, world_map
from .world import MapError, World

log = logging.getLogger("spikinglab.world")


def parser() -> argparse.ArgumentParser:
    p = Parser(prog="spikinglab world", description="The insect's world, on the bus.", together=[shards_fit])
    add_world_args(p)
    p.add_argument(
        "--out",
        type=output_folder,
        help="write metrics.json (collisions over time, learning time, ...) here",
    )
    p.add_argument(
        "--publish-state",
        action="store_true",
        help="publish poses and events every tick (recorder; a world shard: its slice's, which the recorder joins)",
    )
    p.add_argument("--progress", action="store_true", help="show a progress bar")
    p.add_argument(
        "--log-file",
        type=output_file,
        help="also write the log's lines here (they stay on the terminal, beside the progress bar)",
    )
    p.add_argument(
        "--shards",
        type=at_least(1),
        default=1,
        metavar="N",
        help="the brain runs as N shards (brain --shard I/N): each is sent its slice of the agents and the "
        "world waits for all of them every tick (default 1)",
    )
    p.add_argument(
        "--shard",
        type=shard_of_n,
        default=(1, 1),
        metavar="I/N",
        help="step shard I of N of the population (agents in arenas of their own): N worlds run it as one, "
        "shard 1 naming and ending the run (docs/shards.md; default 1/1: all of them)",
    )
    p.add_argument(
        "--checkpoint",
        type=output_folder,
        metavar="DIR",
        help="keep the whole world here every --checkpoint-every ticks, and resume the run kept here "
        "(with the same options) if there is one; the brain keeps its own (brain --checkpoint)",
    )
    p.add_argument(
        "--checkpoint-every",
        type=at_least(1),
        default=10_000,
        metavar="TICKS",
        help="ticks between checkpoints (default %(default)s)",
    )
    add_bus_args(p)
    return p


@dataclass(frozen=True)
class WorldConfig:
    """The world service's options (parser()), typed: what run() and its parts take."""

    world: WorldOptions
    out: Path | None
    publish_state: bool
    progress: bool
    log_file: Path | None  # read by services.runtime, which sets up the log
    shards: int
    shard: tuple[int, int]
    checkpoint: Path | None
    checkpoint_every: int
    bus: BusConfig


def run(config: WorldConfig, session) -> int:
    try:
        world = world_from(config.world, config.shards, config.shard)
        file_digest(config.world.map)  # read with the map: its checkpoints name the map it loaded
        trajectory = Trajectory(world, config.world.ticks)
        resumed = resume(config.checkpoint, config.world, world, trajectory) if config.checkpoint else None
        if config.checkpoint:  # one the brain may not have answered: the run goes on from CHECKPOINT
            (config.checkpoint / PENDING).unlink(missing_ok=True)
    except (MapError, ValueError) as e:
        log.error("%s", e)
        return 2
    terms = None
    if config.shard[1] > 1:
        try:
            mine = shards.terms(config.world, "", config.shard[1], config.shards)
            bus, terms = shards.join(session, config.bus.group, config.shard, mine)
        except (shards.ShardTwice, shards.ShardsDisagree, shards.RunUnderWay) as e:
            log.error("%s", e)
            return 2
    else:
        bus = Bus(session, config.bus.group, keys.world_service(config.shard))
    bus.watch_others(lambda: f" at tick {world.tick}")
    try:
        return run_on(bus, config, world, trajectory, resumed, terms)
    finally:
        bus.close()


def run_on(
    bus: Bus, config: WorldConfig, world: World, trajectory: Trajectory, resumed: str | None, terms: RunTerms | None
) -> int:
    """The run on the bus, from the tick `world` is at: 0 when it ran to its end, 130 when cut short.
    `resumed`: the run kept in the checkpoint; `terms`: a world shard's (shards.join)."""
    start, ticks, group, shard = world.tick, config.world.ticks, bus.group, config.shard
    brains = Brains(bus, group, config.world.agents, config.shards, shard)
    control = bus.outbox(keys.control(group))
    # lossy: a recorder that falls behind or freezes must not hold the run back (it counts the gap)
    state = bus.outbox(keys.world_state(group), lossy=True) if config.publish_state else None
    run_id = resumed or (terms.run if terms else "") or new_run_id()  # what the brain answers and an end names
    if terms is not None and shard[0] == 1:
        shards.lead(bus, terms, run_id, shard)
    lead_ended = shards.LeadsEnd(bus, run_id) if shard[0] > 1 else None
    brains.wait()
    stream = None
    if state is not None:  # a shard's: its slice of the population, which the recorder joins to the others'
        population, n = (config.world.agents, shard[1]) if shard[1] > 1 else (0, 0)
        wait_for_subscriber(state, "a recorder")
        bus.outbox(keys.world_map(group)).put(world_map(world, run_id, population, n))
        stream = StateStream(state, world, run_id, population, n)
    if resumed and config.checkpoint:
        log.info("run %s resumed at tick %d from %s", run_id, start, config.checkpoint / CHECKPOINT)
    log.info(
        "run %s: %d ticks, seed %d, %d agent(s)%s",
        run_id,
        ticks,
        world.seed,
        world.agents,
        f" from agent {world.numbers[0]}, world shard {shard[0]} of {shard[1]}" if shard[1] > 1 else "",
    )
    started = time.perf_counter()
    progress = Progress(world, ticks, config.progress)  # from here on, Ctrl-C ends the run with a result
    interrupted = False
    try:
        requests = brains.send(world, start, run_id, checkpoint=bool(resumed))  # the brain goes back to it too
        tick_loop(config, world, brains, requests, progress, trajectory, stream, lead_ended)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the ticks done are a result too, marked partial
        log.warning("interrupted at tick %d of %d: ending the run there", world.tick, ticks)
        interrupted = True
        if stream is not None:
            stream.send(final=True)
    elapsed = time.perf_counter() - started
    progress.close(world.tick)
    lost = []  # world shards that left the bus before their end
    if lead_ended is None:  # a world, or the lead shard: it ends the run
        lost = shards.end_run(bus, control, shard, Control(tick=world.tick, command="end", run=run_id), interrupted)
    result = metrics_of(world, world.tick, elapsed, start)
    result.update(steady_rate(brains, start, world.tick, started, elapsed))
    result.update(rejected_messages=bus.rejections(), brains_lost_at=brains.lost_at, run=run_id)
    result["partial"] = world.tick < ticks
    log.info("%d ticks in %.1f s (%.0f ticks/s); %s", world.tick, elapsed, result["ticks_per_s"], outcome(result))
    finish(config, result, trajectory, world.tick, lost)
    if lead_ended is not None and not shards.finished(bus, shard, lead_ended, interrupted):  # the lead may end now
        log.error("world shard 1 left the bus before it ended the run: the run has no whole result")
        return 1
    if lost:
        log.error("%s left the bus before the end of its ticks: the run has no result for its insects", ", ".join(lost))
        return 1
    return 0 if world.tick == ticks else 130


def tick_loop(
    config: WorldConfig,
    world: World,
    brains: Brains,
    requests: list[Sensors],
    progress: Progress,
    trajectory: Trajectory,
    stream: StateStream | None,
    lead_ended: shards.LeadsEnd | None = None,
) -> None:
    """The lock-step ticks: each waits for the brain's answer (every shard's) to the last sensors sent.
    The recorder's share of tick t is kept after tick t + 1's sensors are sent, while the brain steps.
    Ctrl-C ends the run once the tick asked for is taken, if its answer comes (Brains.collect): the
    brain has stepped exactly the ticks the world ends the run at (its weights are those ticks').
    `lead_ended`: a world shard's, whether the lead shard has ended the run (cut short there)."""
    spare = world.sensors.copy()  # the next tick's sensors go here while tick t's are kept
    ticks, folder = config.world.ticks, config.checkpoint
    with ctrl_c_in_waits() as waits:
        for t in range(world.tick, ticks):
            if lead_ended is not None and lead_ended():
                log.warning("world shard 1 ended the run at its tick %d: this shard ends it at %d", lead_ended.tick, t)
                return
            actions = brains.collect(world, requests, waits)
            if requests[0].checkpoint and folder:
                checkpoint.confirm(folder)  # the brain has kept this tick too
            world.act(actions)
            trajectory.keep(t)
            sensed = world.sensors  # tick t's
            ending = waits.came  # a Ctrl-C that came before tick t + 1 is asked for ends the run here
            if t + 1 < ticks and not ending:  # the brain's next tick first: the recorder can wait
                keep = folder is not None and (t + 1) % config.checkpoint_every == 0
                if keep and folder:
                    checkpoint.keep_checkpoint(folder, config.world, world, trajectory, requests[0].run)
                if stream is not None:  # sense() fills every value: a swap, not a copy, keeps tick t's
                    world.sensors, spare = spare, world.sensors
                requests = brains.send(world, t + 1, requests[0].run, keep)
            if stream is not None:  # the next sense() left poses, events and changes as act() made them
                stream.keep(t, sensed)
                if stream.full or t + 1 == ticks:
                    stream.send(final=t + 1 == ticks)
            progress.update(t + 1)
            if ending and t + 1 < ticks:
                raise KeyboardInterrupt


def steady_rate(brains: Brains, start: int, done: int, started: float, elapsed: float) -> dict:
    """The first round trip holds the brain's start (its network built, its compiled code loaded):
    what the loop itself runs at is the rate after it, as benchmarks measure after a warm-up."""
    if brains.first_answer_at is None or done - start <= 1:
        return {}
    first = brains.first_answer_at - started
    return {
        "first_tick_s": round(first, 3),
        "steady_ticks_per_s": round((done - start - 1) / max(elapsed - first, 1e-9), 1),
    }


def finish(config: WorldConfig, result: dict, trajectory: Trajectory, done: int, lost: list[str]) -> None:
    """The checkpoints settled and the results written (--out); `lost`: world shards lost (the lead's)."""
    folder, out = config.checkpoint, config.out
    if folder and done == config.world.ticks:
        checkpoint.forget(folder)
    elif folder and (folder / CHECKPOINT).exists():
        log.info("the world command that started this run resumes it from its checkpoint (%s)", folder / CHECKPOINT)
    if out:
        out.mkdir(parents=True, exist_ok=True)
        shard = config.shard
        if shard[1] > 1:
            (out / f"metrics-{keys.shard_name(shard)}.json").write_text(json.dumps(result))
            if shard[0] == 1:  # the others have finished and left: theirs are written
                shards.merge_metrics(out, shard[1], lost, result["run"])
        else:
            (out / "metrics.json").write_text(json.dumps(result))
        if done and shard[0] == 1:  # agent 0's path
            trajectory.save(out / "trajectory.npz", done)


def main(argv=None) -> int:
    return service_main("world", parser(), run, argv, config=WorldConfig)


if __name__ == "__main__":
    sys.exit(main())
