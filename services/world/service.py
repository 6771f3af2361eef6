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
from pathlib import Path

import numpy as np

from services import snapshots
from services.bus import keys
from services.bus.batching import TickBatch, state_batch
from services.bus.config import add_bus_args
from services.bus.schemas import RUN_ID, Array, BusError, Control, Motor, Sensors, WorldMap, WorldState, new_run_id
from services.bus.transport import Bus, wait_for_subscriber
from services.options import Parser, at_least
from services.params import file_for_agents, side_of
from services.runtime import service_main
from services.vocabulary import EVENT_COLUMNS

from .world import PRESETS, SENSORS, MapError, World, map_world, params_for, world_actions

log = logging.getLogger("spikinglab.world")
RESEND_AFTER = 1.0  # seconds without an answer before the sensors are sent again
UNANSWERED_S = 10.0  # a brain on the bus that has not answered a tick for this long is named (then every minute)


def parser() -> argparse.ArgumentParser:
    p = Parser(prog="spikinglab world", description="The insect's world, on the bus.")
    add_world_args(p)
    p.add_argument("--out", type=Path, help="write metrics.json (collisions over time, learning time, ...) here")
    p.add_argument("--publish-state", action="store_true", help="publish poses and events every tick (recorder)")
    p.add_argument("--progress", action="store_true", help="show a progress bar")
    p.add_argument(
        "--shards",
        type=at_least(1),
        default=1,
        metavar="N",
        help="the brain runs as N shards (brain --shard I/N): each is sent its slice of the agents and the "
        "world waits for all of them every tick (default 1)",
    )
    p.add_argument(
        "--checkpoint",
        type=Path,
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


def add_world_args(p: argparse.ArgumentParser) -> None:
    w = p.add_argument_group("world")
    w.add_argument("--ticks", type=at_least(1), default=40_000, help="ticks to run (default %(default)s)")
    w.add_argument("--seed", type=at_least(0), default=0, help="world seed: maps and headings (agent a uses seed + a)")
    w.add_argument("--agents", type=at_least(1), default=1, help="insects stepped together (default 1)")
    w.add_argument("--shared", action="store_true", help="all agents share one arena (default: one each)")
    w.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default="paper",
        help="rotation and move steps: paper (5 deg, 1 patch, default) or netlogo (4 deg, 0.4 patch)",
    )
    w.add_argument("--map", type=Path, help="a text map file instead of the generated arena (docs/world.md)")
    w.add_argument("--no-training", action="store_true", help="no push on noxious patches (test mode)")
    w.add_argument(
        "--learned-after",
        type=at_least(1),
        default=5000,
        help="collision-free ticks that count as learned (default 5,000)",
    )
    w.add_argument(
        "--params",
        type=Path,
        metavar="FILE.csv",
        help="per-agent parameters: a CSV file with a header of names (rotation_step, move_step; the "
        "brain's, such as a_plus or w_max, go to the brain) and a row per agent, or one row for all "
        "(docs/api.md)",
    )


def world_from_args(args: argparse.Namespace) -> World:
    """The World the options describe (MapError / ValueError on a bad map or option)."""
    if args.ticks < 1 or args.agents < 1:
        raise ValueError("--ticks and --agents must be >= 1")
    if getattr(args, "shards", 1) > args.agents:
        raise ValueError(f"--shards {args.shards}: more brain shards than agents ({args.agents})")
    params = params_for(args.preset, learned_after=args.learned_after)
    grid = None
    if args.map:
        params, grid = map_world(args.map, params)
    columns = file_for_agents(args.params, args.agents) if args.params else {}
    return World(
        params,
        agents=args.agents,
        seed=args.seed,
        shared=args.shared,
        grid=grid,
        training=not args.no_training,
        agent_params=side_of(columns, "world"),
    )


def actions_from(message: Motor, agents: int) -> np.ndarray | None:
    """The Motor's actions as [agents, len(ACTIONS)] in the world's order; None if it does not fit."""
    got = message.actions.numpy("actions", "|u1", 2)
    return world_actions(message.names, got) if got.shape[0] == agents else None


class Brains:
    """The brain, or the N shards of a sharded brain, as the world sees them: shard i gets agents
    slices[i] of the population on its own sensors key and answers on the one motor key."""

    def __init__(self, bus: Bus, group: str, agents: int, shards: int):
        self.shards = [(i + 1, shards) for i in range(shards)]
        self.slices = [(agents * i // shards, agents * (i + 1) // shards) for i in range(shards)]
        self.names = ["brain" if shards == 1 else f"brain shard {i}/{n}" for i, n in self.shards]
        self.waited_for = ["a brain" if shards == 1 else name for name in self.names]  # "waiting for ... to subscribe"
        self.sensors = [bus.outbox(keys.sensors(group, s)) for s in self.shards]
        self.presences = [bus.presence(keys.brain_service(s)) for s in self.shards]
        self.motor = bus.inbox(keys.motor(group), Motor)
        self.index = {lo: k for k, (lo, _) in enumerate(self.slices)}  # a slice by its first agent
        self.first_answer_at: float | None = None  # perf_counter when the brain first answered in full

    def wait(self) -> None:
        for outbox, what, presence in zip(self.sensors, self.waited_for, self.presences):
            wait_for_subscriber(outbox, what, presence)

    def send(self, world: World, tick: int, run_id: str, checkpoint: bool = False) -> list[Sensors]:
        """What the world's insects sense for `tick`, each shard's slice sent to it (the seed: the
        brain's netlogo order follows it; `checkpoint`: the world kept its state at the start of
        this tick, the brain keeps its own)."""
        values = world.sense()  # viewed, not copied: sense() fills it again only after collect() got every answer
        requests = [
            Sensors(
                tick=tick,
                names=SENSORS,
                values=Array.view(values[lo:hi]),
                run=run_id,
                seed=world.seed,
                checkpoint=checkpoint,
                first=lo,
            )
            for lo, hi in self.slices
        ]
        for outbox, request in zip(self.sensors, requests):
            outbox.put(request)
        return requests

    def collect(self, world: World, requests: list[Sensors]) -> np.ndarray:
        """Every shard's answer to `requests` (its tick): the actions of all agents. A shard that
        is silent for RESEND_AFTER is asked again, and one that left the bus is named and waited for."""
        t, run_id = requests[0].tick, requests[0].run
        answers = [None] * len(self.shards)
        asked_at, said_at = time.monotonic(), None
        while any(a is None for a in answers):
            answer = self.motor.get(timeout=RESEND_AFTER)
            if answer is None:
                silent = [k for k, a in enumerate(answers) if a is None]
                for k in silent:
                    if not self.presences[k].alive:
                        log.warning("%s lost at tick %d: waiting for it to come back", self.names[k], t)
                        wait_for_subscriber(self.sensors[k], self.waited_for[k], self.presences[k])
                        log.info("%s back: continuing at tick %d", self.names[k], t)
                        asked_at, said_at = time.monotonic(), None
                    self.sensors[k].put(requests[k])
                now = time.monotonic()
                if now - asked_at >= UNANSWERED_S and (said_at is None or now - said_at >= 60):
                    said_at = now  # on the bus, yet silent: most likely it refuses these sensors, and says why
                    log.warning(
                        "%s on the bus but no answer to tick %d for %.0f s: its log says why (a brain "
                        "refuses sensors that do not fit its circuit, parameter file or shard)",
                        " and ".join(self.names[k] for k in silent),
                        t,
                        now - asked_at,
                    )
                continue
            k = self.index.get(answer.first)
            size = None if k is None else self.slices[k][1] - self.slices[k][0]
            if answer.run != run_id:
                self.motor.refuse(
                    BusError(f"another run: motor for run {answer.run!r}, this is {run_id!r}"), f"(tick {answer.tick})"
                )
            elif answer.actions.shape[0] != size:
                self.motor.refuse(
                    BusError(
                        f"does not fit the run: {answer.actions.shape[0]} agents from agent "
                        f"{answer.first}, the world has {world.agents}"
                        + (f" in shards from {[lo for lo, _ in self.slices]}" if len(self.slices) > 1 else "")
                    ),
                    f"(tick {answer.tick})",
                )
            elif answer.tick == t:
                answers[k] = actions_from(answer, size)
        if self.first_answer_at is None:
            self.first_answer_at = time.perf_counter()
        return answers[0] if len(answers) == 1 else np.concatenate(answers)


class Progress:
    """A progress bar with ticks/s, collisions per 1,000 ticks and food (tqdm, on stderr)."""

    def __init__(self, world: World, ticks: int, enabled: bool):
        self.world, self.bar = world, None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(
                total=ticks, initial=world.tick, unit="tick", unit_scale=True, dynamic_ncols=True, mininterval=0.5
            )
        self._shown = world.tick  # a resumed run starts there

    def update(self, tick: int) -> None:
        if self.bar is None or tick - self._shown < 500:
            return
        m = self.world.metrics
        recent = m.bins[-1].mean() if m.bins else m.collisions.mean() * 1000 / max(tick, 1)
        self.bar.set_postfix_str(f"collisions/1k {recent:.1f}, food {m.food.mean():.0f}", refresh=False)
        self.bar.update(tick - self._shown)
        self._shown = tick

    def close(self, tick: int) -> None:
        if self.bar is not None:
            self.bar.update(tick - self._shown)
            self.bar.close()


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


def state_message(batch: TickBatch, changes: list, final: bool, world: World, run: str) -> WorldState:
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
    rows = np.array(changes, np.int64).reshape(-1, 5)
    changes.clear()
    return WorldState(
        tick=first,
        run=run,
        sensor_names=SENSORS,
        sensors=Array.of(a["sensors"]),
        pos=Array.of(a["pos"]),
        heading=Array.of(a["heading"]),
        events=Array.of(a["events"]),
        collisions=Array.of(a["collisions"]),
        food=Array.of(a["food"]),
        changes=Array.of(rows),
        final=final,
    )


def metrics_of(world: World, ticks: int, elapsed: float, resumed_at: int = 0) -> dict:
    m, p = world.metrics, world.params
    return {
        "ticks": ticks,
        "agents": world.agents,
        "seed": world.seed,
        "shared_arena": world.shared,
        "training": world.training,
        "elapsed_s": round(elapsed, 3),
        "ticks_per_s": round((ticks - resumed_at) / max(elapsed, 1e-9), 1),
        "resumed_at": resumed_at or None,  # the tick this process resumed the run at (its checkpoint)
        "world": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(p).items()},
        "collisions_per_1000_ticks": np.array(m.bins).T.tolist() if m.bins else [[] for _ in range(world.agents)],
        "collisions": m.collisions.tolist(),
        "collisions_by_colour": {c: m.collisions_by_colour[:, k].tolist() for k, c in ((1, "black"), (2, "red"))},
        "food": m.food.tolist(),
        "distance": np.round(m.distance, 3).tolist(),
        "resets": m.resets.tolist(),
        "ticks_since_last_collision": [ticks - int(t) if t >= 0 else ticks for t in m.last_collision],
        "learning_time": [int(t) if t >= 0 else None for t in m.learned_at],
        "learning_time_definition": f"the last tick on a noxious patch before the first {p.learned_after} "
        "ticks off them (null: not reached)",
    }


def outcome(result: dict, shown: int = 8) -> str:
    """The log's one line on what the insects did: each one's for a few, a summary for a population."""
    collisions, learned = result["collisions"], result["learning_time"]
    if len(collisions) <= shown:
        return f"collisions {collisions}; learning time {learned}"
    reached = sum(t is not None for t in learned)
    return (
        f"{len(collisions)} insects: collisions {np.mean(collisions):.1f} per insect on average (the first "
        f"{shown}: {collisions[:shown]}); learned: {reached} of {len(learned)}"
    )


class Trajectory:
    """Agent 0's path over the first and the last TRAJECTORY ticks, and the map at both times
    (trajectory.png, the paper's fig. 8: short paths early in training, long ones late)."""

    TICKS = 5000

    def __init__(self, world: World, ticks: int):
        self.world, self.n = world, min(self.TICKS, ticks)
        self.early, self.late = np.full((self.n, 2), np.nan), np.full((self.n, 2), np.nan)
        self.grid_early = world.grid[world.arena_of[0]].copy()

    def keep(self, t: int) -> None:
        if t < self.n:
            self.early[t] = self.world.pos[0]
        self.late[t % self.n] = self.world.pos[0]

    def arrays(self) -> dict[str, np.ndarray]:
        """What a checkpoint keeps of the path (restored in place by snapshots.copy_into)."""
        return {"early": self.early, "late": self.late, "grid_early": self.grid_early}

    def save(self, path: Path, ticks: int) -> None:
        late = np.roll(self.late, -(ticks % self.n), axis=0)  # oldest first
        np.savez_compressed(
            path,
            early=self.early,
            late=late,
            late_from=ticks - self.n,
            grid_early=self.grid_early,
            grid_late=self.world.grid[self.world.arena_of[0]],
            x_min=self.world.params.x_min,
            y_min=self.world.params.y_min,
        )


CHECKPOINT = "world.npz"  # in --checkpoint DIR: the world of one run, at its last checkpoint
# a checkpoint becomes CHECKPOINT once the brain has answered its tick, so has kept its own there:
# a world that dies in between leaves the previous pair, never a world without its brain
PENDING = "world-pending.npz"


def run_options(args: argparse.Namespace) -> dict:
    """The options that make a run what it is: a checkpoint resumes only under the same ones."""
    return {
        "ticks": args.ticks,
        "seed": args.seed,
        "agents": args.agents,
        "shared": args.shared,
        "preset": args.preset,
        "map": str(args.map) if args.map else None,
        "no_training": args.no_training,
        "learned_after": args.learned_after,
    }


def keep_checkpoint(args: argparse.Namespace, world: World, trajectory: Trajectory, run_id: str) -> None:
    arrays = {
        **{f"world.{k}": v for k, v in world.snapshot().items()},
        **{f"trajectory.{k}": v for k, v in trajectory.arrays().items()},
    }
    snapshots.write(
        args.checkpoint / PENDING, arrays, {"run": run_id, "tick": world.tick, "options": run_options(args)}
    )


def resume(args: argparse.Namespace, world: World, trajectory: Trajectory) -> str | None:
    """The run kept in --checkpoint, restored into `world` and `trajectory` (None: nothing kept).
    ValueError when it is not a checkpoint of a run with these options."""
    path = args.checkpoint / CHECKPOINT
    if not path.exists():
        return None
    arrays, meta = snapshots.read(path)
    kept, wanted = meta.get("options", {}), run_options(args)
    differ = [f"--{k.replace('_', '-')} {kept.get(k)} there, {v} here" for k, v in wanted.items() if kept.get(k) != v]
    if differ:
        raise ValueError(
            f"{path} holds run {meta.get('run')} at tick {meta.get('tick')} made with other options "
            f"({'; '.join(differ)}): resume it with those, or give another --checkpoint folder"
        )
    if not RUN_ID.fullmatch(str(meta.get("run"))):
        raise ValueError(f"{path}: not a world checkpoint (no run id in it)")
    world.restore({k.removeprefix("world."): v for k, v in arrays.items() if k.startswith("world.")})
    snapshots.copy_into(
        trajectory.arrays(),
        {k.removeprefix("trajectory."): v for k, v in arrays.items() if k.startswith("trajectory.")},
        str(path),
    )
    return meta["run"]


def run(args: argparse.Namespace, session) -> int:
    try:
        world = world_from_args(args)
        trajectory = Trajectory(world, args.ticks)
        resumed = resume(args, world, trajectory) if args.checkpoint else None
        if args.checkpoint:  # one the brain may not have answered: the run goes on from CHECKPOINT
            (args.checkpoint / PENDING).unlink(missing_ok=True)
    except (MapError, ValueError) as e:
        log.error("%s", e)
        return 2
    start = world.tick
    bus = Bus(session, args.group, "world")
    bus.watch_others(lambda: f" at tick {world.tick}")
    try:
        brains = Brains(bus, args.group, world.agents, args.shards)
        control = bus.outbox(keys.control(args.group))
        # lossy: a recorder that falls behind or freezes must not hold the run back (it counts the gap)
        state = bus.outbox(keys.world_state(args.group), lossy=True) if args.publish_state else None
        brains.wait()
        run_id = resumed or new_run_id()  # the brain answers for this run only; an end names it
        if state is not None:
            wait_for_subscriber(state, "a recorder")
            bus.outbox(keys.world_map(args.group)).put(
                WorldMap(
                    tick=start,
                    run=run_id,
                    grid=Array.of(world.grid),
                    x_min=world.params.x_min,
                    y_min=world.params.y_min,
                )
            )
        batch, changes = TickBatch(state_batch(world.agents)), []
        if resumed:
            log.info("run %s resumed at tick %d from %s", run_id, start, args.checkpoint / CHECKPOINT)
        log.info("run %s: %d ticks, seed %d, %d agent(s)", run_id, args.ticks, world.seed, world.agents)
        started = time.perf_counter()
        progress = Progress(world, args.ticks, args.progress)  # from here on, Ctrl-C ends the run with a result
        try:
            requests = brains.send(world, start, run_id, checkpoint=bool(resumed))  # the brain goes back to it too
            tick_loop(args, world, brains, state, requests, progress, trajectory, batch, changes)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the ticks done are a result too, marked partial
            log.warning("interrupted at tick %d of %d: ending the run there", world.tick, args.ticks)
            if state is not None:
                state.put(state_message(batch, changes, True, world, run_id))
        done = world.tick
        elapsed = time.perf_counter() - started
        progress.close(done)
        control.put(Control(tick=done, command="end", run=run_id))
        result = metrics_of(world, done, elapsed, start)
        if brains.first_answer_at is not None and done - start > 1:
            # the first round trip holds the brain's start (its network built, its compiled code loaded):
            # what the loop itself runs at is the rate after it, as benchmarks measure after a warm-up
            first = brains.first_answer_at - started
            result["first_tick_s"] = round(first, 3)
            result["steady_ticks_per_s"] = round((done - start - 1) / max(elapsed - first, 1e-9), 1)
        result["rejected_messages"] = bus.rejections()
        result["partial"] = done < args.ticks
        log.info("%d ticks in %.1f s (%.0f ticks/s); %s", done, elapsed, result["ticks_per_s"], outcome(result))
        if args.checkpoint and done == args.ticks:  # the run is whole: nothing left to resume
            (args.checkpoint / CHECKPOINT).unlink(missing_ok=True)
            (args.checkpoint / PENDING).unlink(missing_ok=True)
        elif args.checkpoint and (args.checkpoint / CHECKPOINT).exists():
            log.info("the same command resumes this run from its last checkpoint (%s)", args.checkpoint / CHECKPOINT)
        if args.out:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / "metrics.json").write_text(json.dumps(result))
            if done:
                trajectory.save(args.out / "trajectory.npz", done)
        return 0 if done == args.ticks else 130
    finally:
        bus.close()


def tick_loop(args, world, brains, state, requests, progress, trajectory, batch, changes) -> None:
    """The lock-step ticks: each waits for the brain's answer (every shard's) to the last sensors sent.
    The recorder's share of tick t is kept after tick t + 1's sensors are sent, while the brain steps."""
    spare = world.sensors.copy()  # the next tick's sensors go here while tick t's are kept
    for t in range(world.tick, args.ticks):
        actions = brains.collect(world, requests)
        if requests[0].checkpoint and args.checkpoint and (args.checkpoint / PENDING).exists():
            (args.checkpoint / PENDING).replace(args.checkpoint / CHECKPOINT)  # the brain has kept this tick too
        world.act(actions)
        trajectory.keep(t)
        sensed = world.sensors  # tick t's
        if t + 1 < args.ticks:  # the brain's next tick first: the recorder can wait
            keep = args.checkpoint is not None and (t + 1) % args.checkpoint_every == 0
            if keep:
                keep_checkpoint(args, world, trajectory, requests[0].run)
            if state is not None:  # sense() fills every value: a swap, not a copy, keeps tick t's
                world.sensors, spare = spare, world.sensors
            requests = brains.send(world, t + 1, requests[0].run, keep)
        if state is not None:  # the next sense() left poses, events and changes as act() made them
            keep_state(batch, changes, world, t, sensed)
            if batch.full or t + 1 == args.ticks:
                state.put(state_message(batch, changes, t + 1 == args.ticks, world, requests[0].run))
        progress.update(t + 1)


def main(argv=None) -> int:
    return service_main("world", parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
