"""The brain node's protocol logic, without the transport: a Sensors message in, a Motor message
out (lock-step), the run it serves, its checkpoints and the state batches for the recorder.

Lock-step: every Sensors message of tick t is answered by one Motor message of tick t. The number
of agents is taken from the first message. A repeated tick (the world re-sends when it heard
nothing) is answered again from the cache, never stepped twice; an older tick is ignored; tick 0
after others is a new run and resets the brain.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from services import snapshots
from services.bus import keys
from services.bus.batching import TickBatch, state_batch
from services.bus.schemas import Array, BrainLayout, BrainState, BusError, Control, Motor, Sensors
from services.bus.transport import QUIET_S
from services.options import shard_slice, shards_meet
from services.params import side_of

from .brain import Brain, check_sensors

log = logging.getLogger("spikinglab.brain")
FREE_STATE_BATCH = 50  # ticks per BrainState message when free-running: 50 ms behind at 1 kHz for a live view


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
        world_shards: int = 1,
        **engine_options,
    ):
        """`params`: per-agent parameter columns of the whole population (services.params.read_params);
        `free_running`: on a clock (robot), state batches of FREE_STATE_BATCH ticks, not sized by agents."""
        self.circuit, self.training, self.initial_weights = circuit, training, weights
        self.params = side_of(params or {}, "brain")
        self.shard = shard  # (i, n): this brain serves the i-th of n slices of the population
        self.world_shards = world_shards  # the world's shards: each sends this brain a piece of its slice
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
        self.kept_by_world = ""  # the last run whose world said it keeps a checkpoint (one it may resume)
        self.quiet_s, self.heard_at = quiet_s, 0.0  # when the run served last asked (monotonic)

    def compile_kernels(self) -> None:
        """Compile (or load from the kernel cache) the kernels of a one-agent brain, as start() will
        for a robot's first reading. A free-running brain does it before it subscribes to anything:
        on an empty cache the compile holds the interpreter for most of a minute, and a robot's
        readings, thousands a second, left the bus's callbacks waiting until the brain's session
        lapsed (the gateway saw the brain leave the bus, 17 s into the compile)."""
        options = {"seed": 0, **{k: v for k, v in self.engine_options.items() if v is not None}}
        sensors = tuple(self.circuit.sensors)
        brain = Brain(self.circuit, sensors, tuple(self.circuit.actuators), training=self.training, **options)
        nothing = np.full((1, len(sensors)), np.nan)
        brain.step(nothing)  # as the brain steps when its reading is stale
        nothing.flags.writeable = False
        brain.step(nothing)  # and on a reading: a read-only view of the message, another type to numba

    @property
    def running(self) -> Brain:
        """The brain of the run served (start() makes it)."""
        if self.brain is None:
            raise RuntimeError("no run started yet")
        return self.brain

    def new_batch(self) -> TickBatch:
        return TickBatch(FREE_STATE_BATCH if self.free_running else state_batch(self.running.agents))

    def start(self, message: Sensors) -> None:
        """A fresh brain for the sensors and agents of `message` (a new run)."""
        agents = message.values.shape[0]
        params = self.params_of(message.first, agents)  # first: a message that does not fit changes nothing
        loaded = self.initial_weights
        if loaded is not None and loaded.shape[0] not in (1, agents):
            raise BusError(
                f"does not fit the --load weights: they hold {loaded.shape[0]} agents, the world sends {agents}"
            )
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
        if loaded is not None:  # one agent's weights are given to every agent
            self.running.engine.set_weights(loaded[0] if loaded.shape[0] == 1 else loaded)
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
        population the columns give, or a piece of it that one world shard steps (BusError if the
        world sends other agents)."""
        rows = {len(column) for column in self.params.values()} - {1}
        if not rows:
            return self.params  # one value for every agent
        population = rows.pop()
        lo, hi = shard_slice(population, self.shard)
        worlds = self.world_shards
        if (first, first + agents) not in [
            shards_meet(population, (k, worlds), self.shard) for k in range(1, worlds + 1)
        ]:
            i, n = self.shard
            raise BusError(
                f"does not fit the parameter file: its {population} agents make agents {lo}-{hi - 1} "
                f"this brain's (shard {i}/{n}{f', in pieces of {worlds} world shards' if worlds > 1 else ''}); "
                f"the world sends agents {first}-{first + agents - 1}"
            )
        end = first + agents
        return {name: column if len(column) == 1 else column[first:end] for name, column in self.params.items()}

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
            several = "" if self.world_shards > 1 else " (pieces of several world shards: --world-shards N)"
            raise BusError(
                f"another slice: agents from {message.first}, this brain serves agents from {self.first}{several}"
            )
        if message.names != self.running.sensor_names or values.shape[0] != self.running.agents:
            raise BusError(
                f"does not fit the run: {values.shape[0]} agents with sensors {list(message.names)}, this "
                f"brain serves {self.running.agents} with {list(self.running.sensor_names)}"
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
            self.kept_by_world = message.run
            self.keep_checkpoint(message.tick)
        actions = self.running.step(values)
        self.last_tick, self.stepped = message.tick, True
        self.last_answer = Motor(
            tick=message.tick,
            names=self.running.action_names,
            actions=Array.of(actions),
            run=self.run or "",
            first=self.first,
        )
        return self.last_answer

    def checkpoint_name(self) -> str:
        """brain-<run>, or brain-<run>-<i>of<n> for a shard: the shards of one run share a folder."""
        return f"brain-{self.run}" + (f"-{keys.shard_name(self.shard)}" if self.shard[1] > 1 else "")

    def checkpoint_path(self, tick: int) -> Path:
        if self.checkpoints is None:
            raise ValueError("no --checkpoint folder")
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
                path, self.running.engine.snapshot(), {"run": self.run, "tick": tick, "circuit": self.circuit.name}
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
            self.running.engine.restore(arrays)
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
        """Whether `order` ends this node's run: an "end" for the run it serves, not before its last
        tick. A sharded world's end names its lead shard's tick, and a piece of another shard,
        not in step with the lead, may be past it: there the run is checked, not the tick, but for
        the piece from agent 0, which the lead itself sends."""
        if self.brain is None:  # e.g. brain --shard 3/3 beside a world of --shards 2, which sends it nothing
            raise BusError(
                f"does not fit the run: end of run {order.run!r} at tick {order.tick}, and this brain has served "
                "no piece of a run yet (a world of --shards N sends pieces to brain shards 1/N .. N/N)"
            )
        stale = order.tick < self.last_tick and (self.world_shards == 1 or self.first == 0)
        if order.run != self.run or stale:
            raise BusError(
                f"does not fit the run: end of run {order.run!r} at tick {order.tick}, the brain serves "
                f"run {self.run!r} at tick {self.last_tick}"
            )
        return True

    def keep_state(self) -> None:
        """Note this tick's spikes and potentials for the next BrainState batch."""
        engine = self.running.engine
        self.batch.add(self.last_tick, spiked=engine.spiked.view(np.uint8), potentials=engine.v.astype(np.float32))

    def state_message(self, final: bool = False) -> BrainState:
        """The ticks noted so far (possibly none, for a final one) and the weights now."""
        engine = self.running.engine
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
