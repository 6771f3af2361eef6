"""The brain service: `spikinglab brain` / `python -m services.brain`.

Reads:  spikinglab/<group>/sensors (Sensors), spikinglab/<group>/control (Control)
Writes: spikinglab/<group>/motor (Motor), liveliness spikinglab/<group>/alive/brain

Lock-step: every Sensors message of tick t is answered by one Motor message of tick t. The number
of agents is taken from the first message. A repeated tick (the world re-sends when it heard
nothing) is answered again from the cache, never stepped twice; an older tick is ignored; tick 0
after others is a new run and resets the brain. On Control "end" the brain saves its weights
(--save) and exits.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

from services import snapshots
from services.bus import keys
from services.bus.batching import TickBatch, state_batch
from services.bus.config import add_bus_args
from services.bus.schemas import Array, BrainLayout, BrainState, BusError, Control, Motor, Sensors
from services.bus.transport import QUIET_S, Bus, wait_for_subscriber
from services.options import Parser, at_least, not_negative, number, positive, shard
from services.params import file_rows, read_params, side_of
from services.runtime import service_main

from .brain import Brain, check_sensors
from .checkpoint import load_weights, save_weights
from .circuit import CircuitError, load_circuit
from .engine import DEFAULT_SEMANTICS, ORDERS, SEMANTICS, learning_tables

log = logging.getLogger("spikinglab.brain")
FREE_STATE_BATCH = 50  # ticks per BrainState message when free-running: 50 ms behind at 1 kHz for a live view
HEARTBEAT_S = 0.05  # free-running: a motor message (an empty one if nothing fired) at least this often
CATCH_UP_S = 0.05  # free-running: a clock this far behind skips ahead instead of running the missed ticks


def parser() -> argparse.ArgumentParser:
    p = Parser(prog="spikinglab brain", description="The spiking-network brain, on the bus.")
    p.add_argument(
        "--circuit", default="insect", help="circuit name in services/brain/circuits/ or a .toml path (default insect)"
    )
    p.add_argument("--a-plus", type=number, help="A+ = A- of the learning neurons (default: the circuit's)")
    p.add_argument("--no-training", action="store_true", help="weights stay as they are")
    p.add_argument(
        "--params",
        type=Path,
        metavar="FILE.csv",
        help="per-agent parameters: a CSV file with a header of names (a_plus, a_minus, tau_plus, "
        "tau_minus, w_max, initial_weight, input_gain; the world's go to the world) and a row per "
        "agent of the whole population, or one row for all (docs/api.md); a shard takes its slice",
    )
    add_engine_args(p)
    p.add_argument(
        "--seed",
        type=at_least(0),
        default=None,
        help="the netlogo order's seed, agent a using seed + a (default: the world's seed, which its "
        "sensor messages carry, so that a run is the same in one process or across the bus)",
    )
    p.add_argument("--load", type=Path, help="start from the weights in this checkpoint (.npz)")
    p.add_argument("--save", type=Path, help="write the final weights here (.npz) when the run ends")
    p.add_argument("--once", action="store_true", help="exit after one run ends (default: serve the next run)")
    p.add_argument(
        "--shard",
        type=shard,
        default=(1, 1),
        metavar="I/N",
        help="serve shard I of N of the population (the world, started with --shards N, sends each its "
        "slice of the agents; default 1/1: all of them)",
    )
    p.add_argument(
        "--checkpoint",
        type=Path,
        metavar="DIR",
        help="keep the brain's whole state here whenever the world keeps a checkpoint (world "
        "--checkpoint), the last two per run: a resumed run goes back to them tick for tick",
    )
    p.add_argument(
        "--stats",
        type=Path,
        help="write the rejected messages (and, free-running, the tick rate and lateness) here (JSON) when a run ends",
    )
    p.add_argument(
        "--publish-state",
        action="store_true",
        help="publish spikes and potentials of every tick, and the weights, in batches of 50 to 250 ticks "
        f"(fewer for more agents; {FREE_STATE_BATCH} free-running) for the recorder; the first tick "
        "waits until someone subscribes",
    )
    free = p.add_argument_group("free-running (robot)")
    free.add_argument(
        "--clock",
        type=not_negative,
        default=0,
        metavar="HZ",
        help="tick on this clock with the latest sensor reading, motor spikes as events "
        "(robot mode, e.g. 1000); default 0: lock-step with a world",
    )
    free.add_argument(
        "--stale-after",
        type=positive,
        default=0.5,
        help="seconds after which a reading no longer counts as sensed (default 0.5)",
    )
    free.add_argument(
        "--no-realtime",
        action="store_true",
        help="do not ask for real-time scheduling of the clock thread (asked by default; needs "
        "root or CAP_SYS_NICE on Linux, else the normal scheduler is used)",
    )
    add_bus_args(p)
    return p


def add_engine_args(p: argparse.ArgumentParser) -> None:
    """The engine's semantics options, shared by `brain`, `run` and `sweep`."""
    p.add_argument(
        "--semantics",
        choices=SEMANTICS,
        default=DEFAULT_SEMANTICS,
        help=f"phased: five phases, a delay of d is exactly d; netlogo: the original NetLogo engine's "
        f"turns (docs/tick.md) (default {DEFAULT_SEMANTICS})",
    )
    p.add_argument(
        "--order",
        choices=ORDERS,
        default="random",
        help="netlogo: neurons each tick in a seeded random order (as NetLogo's ask) or in file order",
    )


def brain_params(path: Path, circuit) -> dict:
    """The --params file's columns (all of them: a shard slices them by its sensors' agents), checked
    against the circuit before any run: ValueError for a value it cannot take (a w_max below its
    initial weights)."""
    columns = read_params(path)
    try:
        learning_tables(circuit, side_of(columns, "brain"), file_rows(columns))
    except ValueError as e:
        raise ValueError(f"parameter file {path}: {e}") from None
    return columns


class BrainNode:
    """The lock-step logic, without the transport: a Sensors message in, a Motor message out."""

    def __init__(
        self,
        circuit,
        training: bool = True,
        weights: np.ndarray | None = None,
        checkpoints: Path | None = None,
        quiet_s: float = QUIET_S,
        shard: tuple[int, int] = (1, 1),
        params: dict | None = None,
        free_running: bool = False,
        **engine_options,
    ):
        """`params`: per-agent parameter columns of the whole population (services.params.read_params);
        `free_running`: on a clock (robot), state batches of FREE_STATE_BATCH ticks, not sized by agents."""
        self.circuit, self.training, self.initial_weights = circuit, training, weights
        self.params = side_of(params or {}, "brain")
        self.shard = shard  # (i, n): this brain serves the i-th of n slices of the population
        self.first = 0  # the population's index of this brain's first agent (its sensors say it)
        self.checkpoints = checkpoints  # the folder of this brain's whole-state checkpoints (None: none kept)
        self.engine_options = engine_options  # semantics, order, seed
        self.brain: Brain | None = None
        self.free_running = free_running
        self.batch = TickBatch(FREE_STATE_BATCH)  # spikes and potentials not yet published (start() sizes it)
        self.stepped = False  # whether the last answer() stepped the brain (not a repeat)
        self.last_tick = -1
        self.run: str | None = None  # the run served, as its sensor messages name it
        self.last_answer: Motor | None = None
        self.warned = False  # said that the world keeps checkpoints and this brain does not
        self.quiet_s, self.heard_at = quiet_s, 0.0  # when the run served last asked (monotonic)

    def new_batch(self) -> TickBatch:
        return TickBatch(FREE_STATE_BATCH if self.free_running else state_batch(self.brain.agents))

    def start(self, message: Sensors) -> None:
        """A fresh brain for the sensors and agents of `message` (a new run)."""
        agents = message.values.shape[0]
        params = self.params_of(message.first, agents)  # first: a message that does not fit changes nothing
        options = dict(self.engine_options)
        if options.get("seed") is None:
            options["seed"] = message.seed
        self.first = message.first
        options["seed"] += message.first  # agent k of a slice is agent first + k of the population
        self.brain = Brain(
            self.circuit,
            message.names,
            tuple(self.circuit.actuators),
            agents=agents,
            training=self.training,
            params=params,
            **options,
        )
        if self.initial_weights is not None:  # one agent's weights are given to every agent
            w = self.initial_weights
            self.brain.engine.set_weights(w[0] if w.shape[0] == 1 else w)
        self.batch = self.new_batch()  # nothing of a previous run goes into this one's batches
        log.info(
            "brain for %d agent(s) of circuit %s, sensors %s, training %s, %s",
            agents,
            self.circuit.name,
            ", ".join(message.names),
            "on" if self.training else "off",
            ", ".join(f"{k} {v}" for k, v in options.items()),
        )

    def params_of(self, first: int, agents: int) -> dict:
        """The per-agent columns of agents first.. first + agents - 1: this shard's slice of the
        population the columns give (BusError if the world sends other agents)."""
        rows = {len(column) for column in self.params.values()} - {1}
        if not rows:
            return self.params  # one value for every agent
        population = rows.pop()
        i, n = self.shard
        lo, hi = population * (i - 1) // n, population * i // n
        if (first, first + agents) != (lo, hi):
            raise BusError(
                f"does not fit the parameter file: its {population} agents make agents {lo}-{hi - 1} "
                f"this brain's (shard {i}/{n}); the world sends agents {first}-{first + agents - 1}"
            )
        return {name: column if len(column) == 1 else column[lo:hi] for name, column in self.params.items()}

    def starts_run(self, message: Sensors) -> bool:
        """Whether `message` starts a run this node does not serve: its tick 0, or a resumed run's
        first tick (a checkpoint), once the run served has gone quiet; or whatever comes first."""
        if self.brain is None:
            return True
        return (
            message.run != self.run
            and (message.tick == 0 or message.checkpoint)
            and time.monotonic() - self.heard_at > self.quiet_s
        )

    def answer(self, message: Sensors) -> Motor | None:
        """The Motor answer to `message`, or None for an older tick (the world moved on). A message
        that does not fit (another run mid-run, other agents or sensors) raises BusError."""
        self.stepped = False
        values = message.values.numpy("values", "<f8", 2)
        if self.starts_run(message):
            try:
                check_sensors(self.circuit, message.names)
            except ValueError as e:
                raise BusError(f"does not fit the circuit: {e}") from None
            if self.brain is not None:
                log.info("run %s starts: the brain starts afresh", message.run)
            self.start(message)
            self.run, self.last_tick = message.run, -1
            if message.tick > 0:
                self.go_back(message, joining=True)
        if message.run != self.run:
            raise BusError(
                f"another run: sensors of run {message.run!r} at tick {message.tick}, the brain serves run {self.run!r}"
            )
        self.heard_at = time.monotonic()
        if message.first != self.first:
            raise BusError(f"another slice: agents from {message.first}, this brain serves agents from {self.first}")
        if message.names != self.brain.sensor_names or values.shape[0] != self.brain.agents:
            raise BusError(
                f"does not fit the run: {values.shape[0]} agents with sensors {list(message.names)}, this "
                f"brain serves {self.brain.agents} with {list(self.brain.sensor_names)}"
            )
        if message.checkpoint and message.tick < self.last_tick:  # the world resumed the run from there
            self.go_back(message)
        if message.tick == self.last_tick:
            return self.last_answer  # the world asks again: same answer, no second step
        if message.tick < self.last_tick:
            return None
        if self.last_tick >= 0 and message.tick != self.last_tick + 1:
            log.info("joined at tick %d (last seen %d)", message.tick, self.last_tick)
        if message.checkpoint:
            self.keep_checkpoint(message.tick)
        actions = self.brain.step(values)
        self.last_tick, self.stepped = message.tick, True
        self.last_answer = Motor(
            tick=message.tick, names=self.brain.action_names, actions=Array.of(actions), run=self.run, first=self.first
        )
        return self.last_answer

    def checkpoint_name(self) -> str:
        """brain-<run>, or brain-<run>-<i>of<n> for a shard: the shards of one run share a folder."""
        return f"brain-{self.run}" + (f"-{keys.shard_name(self.shard)}" if self.shard[1] > 1 else "")

    def checkpoint_path(self, tick: int) -> Path:
        return self.checkpoints / f"{self.checkpoint_name()}-tick{tick}.npz"

    def keep_checkpoint(self, tick: int) -> None:
        """The whole brain at the start of `tick`, where the world keeps its own; the last two of the run."""
        if self.checkpoints is None:
            if not self.warned:
                log.warning(
                    "the world keeps checkpoints of run %s but this brain does not (no --checkpoint): a "
                    "resumed run would start the brain afresh",
                    self.run,
                )
                self.warned = True
            return
        path = self.checkpoint_path(tick)
        if not path.exists():  # a repeat of the tick: already kept
            snapshots.write(
                path, self.brain.engine.snapshot(), {"run": self.run, "tick": tick, "circuit": self.circuit.name}
            )
        kept = sorted(
            self.checkpoints.glob(f"{self.checkpoint_name()}-tick*.npz"), key=lambda p: int(p.stem.rsplit("tick", 1)[1])
        )
        for old in kept[:-2]:
            old.unlink(missing_ok=True)

    def go_back(self, message: Sensors, joining: bool = False) -> None:
        """To the start of `message.tick` of this run, from the checkpoint kept there. A brain that
        joins a run without one starts afresh at that tick (said); one asked to go back raises BusError."""
        path = self.checkpoint_path(message.tick) if self.checkpoints else None
        try:
            if path is None or not path.exists():
                raise ValueError(
                    f"no checkpoint of run {self.run} at tick {message.tick}"
                    + (f" in {self.checkpoints}" if self.checkpoints else " (no --checkpoint)")
                )
            arrays, meta = snapshots.read(path)
            if meta.get("circuit") != self.circuit.name:
                raise ValueError(f"{path}: a brain of circuit {meta.get('circuit')!r}, this is {self.circuit.name!r}")
            self.brain.engine.restore(arrays)
        except ValueError as e:
            if not joining:
                raise BusError(f"cannot resume: {e}") from None
            log.warning(
                "joined run %s at tick %d afresh (%s): the learning before it is not in this brain",
                self.run,
                message.tick,
                e,
            )
            return
        self.last_tick, self.last_answer = message.tick - 1, None
        self.batch = self.new_batch()
        log.info("run %s resumed at tick %d from %s", self.run, message.tick, path)

    def ends(self, order: Control) -> bool:
        """Whether `order` ends this node's run: an "end" for the run it serves, not before its last tick."""
        if self.brain is None or order.run != self.run or order.tick < self.last_tick:
            raise BusError(
                f"does not fit the run: end of run {order.run!r} at tick {order.tick}, the brain serves "
                f"run {self.run!r} at tick {self.last_tick}"
            )
        return True

    def keep_state(self) -> None:
        """Note this tick's spikes and potentials for the next BrainState batch."""
        engine = self.brain.engine
        self.batch.add(self.last_tick, spiked=engine.spiked.view(np.uint8), potentials=engine.v.astype(np.float32))

    def state_message(self, final: bool = False) -> BrainState:
        """The ticks noted so far (possibly none, for a final one) and the weights now."""
        engine = self.brain.engine
        first, rows = self.batch.take()
        if first is None:
            first = self.last_tick + 1
            rows = {
                "spiked": np.zeros((0, engine.agents, engine.spiked.shape[1]), np.uint8),
                "potentials": np.zeros((0, engine.agents, engine.n_neurons), np.float32),
            }
        return BrainState(
            tick=first,
            run=self.run or "",
            spiked=Array.of(rows["spiked"]),
            potentials=Array.of(rows["potentials"]),
            weights=Array.of(engine.w),
            final=final,
        )


def layout(circuit, tick: int, run: str = "") -> BrainLayout:
    return BrainLayout(
        tick=tick,
        run=run,
        circuit=circuit.name,
        nodes=circuit.node_names,
        neurons=len(circuit.neuron_names),
        synapses=tuple(circuit.synapse_label(k) for k in range(len(circuit.synapses))),
        plastic=tuple(circuit.plastic_synapses),
    )


def run(args: argparse.Namespace, session) -> int:
    try:
        circuit = load_circuit(args.circuit)
        if args.a_plus is not None:
            circuit = circuit.with_learning_rate(args.a_plus)
        weights = load_weights(args.load, circuit) if args.load else None
        params = brain_params(args.params, circuit) if args.params else None
    except (CircuitError, ValueError, OSError) as e:
        log.error("%s", e)
        return 2
    if args.shard[1] > 1 and (args.publish_state or args.clock):
        log.error(
            "--shard %d/%d: a sharded brain serves a world in lock-step and does not publish its state (the "
            "recorder takes one brain's; record the world, or run one brain): drop %s",
            *args.shard,
            "--publish-state" if args.publish_state else "--clock",
        )
        return 2

    def new_node() -> BrainNode:  # one per run the brain serves
        return BrainNode(
            circuit,
            training=not args.no_training,
            weights=weights,
            checkpoints=args.checkpoint,
            shard=args.shard,
            params=params,
            free_running=bool(args.clock),
            seed=args.seed,
            semantics=args.semantics,
            order=args.order,
        )

    node = new_node()
    bus = Bus(session, args.group, keys.brain_service(args.shard))
    bus.watch_others(lambda: f" at tick {node.last_tick + 1} of run {node.run}" if node.run else "")
    if args.clock:
        try:
            return run_free(args, bus, node)
        finally:
            bus.close()
    try:
        sensors = bus.inbox(keys.sensors(args.group, args.shard), Sensors)
        control = bus.inbox(keys.control(args.group), Control)
        motor = bus.outbox(keys.motor(args.group))
        state = bus.outbox(keys.brain_state(args.group), lossy=True) if args.publish_state else None
        world = bus.presence("world")
        log.info(
            "brain ready on group %s (%s)%s",
            args.group,
            bus.sender,
            f", shard {args.shard[0]} of {args.shard[1]}" if args.shard[1] > 1 else "",
        )
        kept = None  # (run, tick) whose learning was saved when the run stopped without its end

        def unsaved() -> bool:  # learning of a run that has not ended, not kept yet
            return node.brain is not None and kept != (node.run, node.last_tick)

        while True:
            message = sensors.get(timeout=0.25)
            if message is not None:
                if unsaved() and node.starts_run(message):
                    kept = keep_learning(args, node, circuit, f"run {message.run} starts before it ended")
                serve(node, message, sensors, motor, state, circuit)
            # every turn, all that waits: a flood on the control key must not pile up while the run goes on
            while (order := control.get(timeout=0)) is not None:
                try:
                    node.ends(order)
                except BusError as e:
                    control.refuse(e)
                    continue
                if state is not None and node.brain is not None:  # the rest, and the final weights
                    state.put(node.state_message(final=True))
                log.info("run ended at tick %d; rejected messages: %s", order.tick, bus.rejections() or "none")
                if args.stats:
                    args.stats.write_text(
                        json.dumps({"ticks": node.last_tick + 1, "rejected_messages": bus.rejections()})
                    )
                if args.save and node.brain is not None:
                    save_weights(args.save, node.brain.engine, circuit, tick=order.tick)
                    log.info("weights saved to %s", args.save)
                if args.once:
                    return 0
                node = new_node()
            if message is None and unsaved() and not world.alive:  # gone without an end (read above, had it come)
                kept = keep_learning(args, node, circuit, "its world left the bus")
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM mid-run: the learning so far is kept
        if unsaved():
            keep_learning(args, node, circuit, "the brain was interrupted")
        raise
    finally:
        bus.close()


def serve(node: BrainNode, message: Sensors, sensors, motor, state, circuit) -> None:
    """Answer one Sensors message (lock-step): the Motor first, then the recorder's share."""
    if state is not None and node.last_tick < 0:
        wait_for_subscriber(state, "a recorder")
        state.put(layout(circuit, message.tick, message.run))
    try:
        answer = node.answer(message)
    except BusError as e:
        sensors.refuse(e, f"(tick {message.tick})")
        return
    if answer is not None:
        motor.put(answer)  # first: the world waits for it; the recorder does not
        if state is not None and node.stepped:
            node.keep_state()
            if node.batch.full:
                state.put(node.state_message())


def keep_learning(args, node: BrainNode, circuit, why: str) -> tuple:
    """A run stopped without its end (`why`): its weights so far are saved beside --save, never
    lost to the next run. Returns (run, last tick): what was kept."""
    if not args.save:
        log.warning(
            "run %s stopped at tick %d without its end (%s); its weights are not saved (no --save)",
            node.run,
            node.last_tick,
            why,
        )
        return node.run, node.last_tick
    path = args.save.with_name(f"{args.save.stem}-{node.run}-tick{node.last_tick + 1}.npz")
    save_weights(path, node.brain.engine, circuit, tick=node.last_tick + 1)
    log.warning(
        "run %s stopped at tick %d without its end (%s): its weights so far saved to %s",
        node.run,
        node.last_tick + 1,
        why,
        path,
    )
    return node.run, node.last_tick


def realtime_clock() -> None:
    """SCHED_FIFO for this (the clock's) thread only: the kernel then runs it the moment its sleep
    ends instead of after the time slice of whatever else shares its core (zenoh's threads do). It
    sleeps most of each tick, so those threads still run."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        log.info("clock thread on real-time scheduling (SCHED_FIFO)")
    except (OSError, AttributeError) as e:
        log.info("clock thread on the normal scheduler (real-time not permitted: %s)", e)


def run_free(args: argparse.Namespace, bus: Bus, node: BrainNode) -> int:
    """Robot mode: tick at --clock Hz with the latest reading; a Motor message only when an action fired.

    Each tick is due at start + k / Hz (no drift); the loop sleeps until shortly before that and
    spins the rest, because a plain sleep wakes up to ~0.1 ms late, more under load.
    """
    sensors = bus.inbox(keys.sensors(args.group), Sensors)
    control = bus.inbox(keys.control(args.group), Control)
    motor = bus.outbox(keys.motor(args.group))
    state = bus.outbox(keys.brain_state(args.group), lossy=True) if args.publish_state else None
    latest, latest_at = None, 0.0
    log.info(
        "brain ready on group %s (%s), free-running at %g Hz; waiting for sensors", args.group, bus.sender, args.clock
    )
    while latest is None:  # the first reading that fits the circuit tells the sensors and the agents
        latest = sensors.get(timeout=0.25)
        if latest is not None:
            try:
                check_sensors(node.circuit, latest.names)
            except ValueError as e:
                sensors.refuse(BusError(f"does not fit the circuit: {e}"))
                latest = None
    latest_at = time.monotonic()
    node.start(latest)
    node.run = latest.run
    engine, brain = node.brain.engine, node.brain
    nothing = np.full(latest.values.shape, np.nan)
    if state is not None:
        wait_for_subscriber(state, "a recorder")
        state.put(layout(node.circuit, 0, node.run))
    if not args.no_realtime:
        realtime_clock()
    period = 1.0 / args.clock
    lateness = []
    started = next_at = spoke_at = time.monotonic()
    tick = 0
    try:
        while True:
            message = sensors.latest()  # only the newest reading counts
            now = time.monotonic()
            fresh = now - latest_at < args.stale_after
            if message is not None:
                if message.names != latest.names or message.values.shape != latest.values.shape:
                    sensors.refuse(
                        BusError(f"does not fit the run: {list(message.values.shape)} sensors of {list(message.names)}")
                    )
                elif message.run != latest.run and fresh:  # a new run once the robot's has gone quiet
                    sensors.refuse(BusError(f"another run: {message.run!r}, the robot's is {latest.run!r}"))
                else:
                    if message.run != latest.run:
                        log.info("the robot's run is now %s (%s went quiet)", message.run, latest.run)
                    latest, latest_at, fresh = message, now, True
            values = latest.values.numpy("values", "<f8", 2) if fresh else nothing
            actions = brain.step(values)
            node.last_tick = tick
            if actions.any() or now - spoke_at > HEARTBEAT_S:  # silence would mean a stalled brain
                motor.put(
                    Motor(
                        tick=tick,
                        names=brain.action_names,
                        actions=Array.of(actions),
                        run=latest.run,
                        reading=latest.tick,
                    )
                )
                spoke_at = now
            if state is not None:
                node.keep_state()
                if node.batch.full:
                    state.put(node.state_message())
            if tick % 100 == 0:
                order = control.get(timeout=0)
                if order is not None and order.run == latest.run:
                    break
                if order is not None:
                    control.refuse(
                        BusError(f"another run: end of run {order.run!r}, the robot's run is {latest.run!r}")
                    )
            tick += 1
            next_at += period
            behind = time.monotonic() - next_at
            if behind > CATCH_UP_S:  # stalled (stopped, starved): go on from now, no burst of old ticks
                log.warning("the clock stalled for %.2f s: %d ticks skipped", behind, int(behind / period))
                next_at = time.monotonic()
            gap = next_at - time.monotonic()
            if gap > 0.0003:
                time.sleep(gap - 0.0003)
            while time.monotonic() < next_at:
                pass
            lateness.append(time.monotonic() - next_at)
    except KeyboardInterrupt:
        pass
    if state is not None:
        state.put(node.state_message(final=True))
    elapsed = time.monotonic() - started
    late_ms = np.array(lateness) * 1000 if lateness else np.zeros(1)
    stats = {
        "ticks": tick,
        "hz": round(tick / elapsed, 1),
        "late_ms_median": round(float(np.median(late_ms)), 4),
        "late_ms_p99": round(float(np.percentile(late_ms, 99)), 4),
        "late_ms_max": round(float(late_ms.max()), 3),
        "rejected_messages": bus.rejections(),
    }
    log.info(
        "free-running brain stopped after %d ticks: %.1f Hz, lateness median %.3f ms, p99 %.3f ms",
        tick,
        stats["hz"],
        stats["late_ms_median"],
        stats["late_ms_p99"],
    )
    if args.stats:
        args.stats.write_text(json.dumps(stats))
    if args.save:
        save_weights(args.save, engine, node.circuit, tick=tick)
    return 0


def main(argv=None) -> int:
    return service_main("brain", parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
