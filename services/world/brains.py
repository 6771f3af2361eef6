"""The brain as the world sees it on the bus: one brain, or the N shards of a sharded brain, each
sent its slice of the agents' sensors every tick and waited for until it answers."""

from __future__ import annotations

import logging
import time

import numpy as np

from services.bus import keys
from services.bus.schemas import Array, BusError, Motor, Sensors
from services.bus.transport import Bus, wait_for_subscriber
from services.interrupts import Waits
from services.options import shard_slice, shards_meet

from .world import SENSORS, World, world_actions

log = logging.getLogger("spikinglab.world")
RESEND_AFTER = 1.0  # seconds without an answer before the sensors are sent again
LAST_ANSWER_S = 2.0  # after Ctrl-C: how long the world still waits for the answer to the tick it asked for
UNANSWERED_S = 10.0  # a brain on the bus that has not answered a tick for this long is named (then every minute)


def actions_from(message: Motor, agents: int) -> np.ndarray | None:
    """The Motor's actions as [agents, len(ACTIONS)] in the world's order; None if it does not fit."""
    got = message.actions.numpy("actions", "|u1", 2)
    return world_actions(message.names, got) if got.shape[0] == agents else None


class Brains:
    """The brain, or the N shards of a sharded brain, as the world (or world shard `world_shard` of
    a population of `agents`) sees them: shard i gets agents slices[i] of the population (those of
    its slice this world steps) on its own sensors key and answers on the one motor key."""

    def __init__(self, bus: Bus, group: str, agents: int, shards: int, world_shard: tuple[int, int] = (1, 1)):
        meets = [((j, shards), shards_meet(agents, world_shard, (j, shards))) for j in range(1, shards + 1)]
        self.shards = [s for s, (lo, hi) in meets if lo < hi]
        self.slices = [(lo, hi) for _, (lo, hi) in meets if lo < hi]
        self.first = shard_slice(agents, world_shard)[0]  # the population's index of this world's agent 0
        # the pieces other world shards step: their answers come on the motor key too, for them
        others = [(i, world_shard[1]) for i in range(1, world_shard[1] + 1) if i != world_shard[0]]
        self.others = {
            lo
            for w in others
            for j in range(1, shards + 1)
            for lo, hi in [shards_meet(agents, w, (j, shards))]
            if lo < hi
        }
        self.names = ["brain" if shards == 1 else f"brain shard {i}/{n}" for i, n in self.shards]
        self.waited_for = ["a brain" if shards == 1 else name for name in self.names]  # "waiting for ... to subscribe"
        self.sensors = [bus.outbox(keys.sensors(group, s)) for s in self.shards]
        self.presences = [bus.presence(keys.brain_service(s)) for s in self.shards]
        self.motor = bus.inbox(keys.motor(group), Motor)
        self.index = {lo: k for k, (lo, _) in enumerate(self.slices)}  # a slice by its first agent
        self.first_answer_at: float | None = None  # perf_counter when the brain first answered in full
        self.lost_at: list[int] = []  # the ticks at which a brain (shard) left the bus mid-run

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
                values=Array.view(values[lo - self.first : hi - self.first]),
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

    def collect(self, world: World, requests: list[Sensors], waits: Waits) -> np.ndarray:
        """Every shard's answer to `requests` (its tick): the actions of all agents. A shard that
        is silent for RESEND_AFTER is asked again, and one that left the bus is named and waited for.
        Ctrl-C is noted in `waits`, not raised here, where it would lose an answer just received:
        the answers are still taken for LAST_ANSWER_S, and KeyboardInterrupt raised if they do not
        come, or at once where a shard that left the bus is waited for."""
        answers: list[np.ndarray | None] = [None] * len(self.shards)
        silence, deadline = Silence(self, requests[0].tick, waits), None
        while any(a is None for a in answers):
            if deadline is None and waits.came:
                deadline = time.monotonic() + LAST_ANSWER_S
            left = RESEND_AFTER if deadline is None else min(RESEND_AFTER, deadline - time.monotonic())
            if left <= 0:
                raise KeyboardInterrupt
            answer = self.motor.get(timeout=left)
            if answer is None:
                silence.ask_again([k for k, a in enumerate(answers) if a is None], requests)
            elif isinstance(answer, Motor):  # (the inbox takes nothing else)
                self.take(answer, world, requests[0], answers)
        if self.first_answer_at is None:
            self.first_answer_at = time.perf_counter()
        got = [a for a in answers if a is not None]
        return got[0] if len(got) == 1 else np.concatenate(got)

    def take(self, answer: Motor, world: World, request: Sensors, answers: list) -> None:
        """Keep `answer` in its shard's place in `answers` if it answers `request`'s tick; refuse
        one of another run or of agents no shard has."""
        if answer.run != request.run:
            self.motor.refuse(
                BusError(f"another run: motor for run {answer.run!r}, this is {request.run!r}"), f"(tick {answer.tick})"
            )
            return
        if answer.first in self.others:
            return  # another world shard's agents, from a brain shard both talk to
        k = self.index.get(answer.first)
        size = -1 if k is None else self.slices[k][1] - self.slices[k][0]
        if k is None or answer.actions.shape[0] != size:
            shards = f" in shards from {[lo for lo, _ in self.slices]}" if len(self.slices) > 1 else ""
            self.motor.refuse(
                BusError(
                    f"does not fit the run: {answer.actions.shape[0]} agents from agent "
                    f"{answer.first}, the world has {world.agents}{shards}"
                ),
                f"(tick {answer.tick})",
            )
        elif answer.tick == request.tick:
            answers[k] = actions_from(answer, size)


class Silence:
    """The shards that have not answered a tick yet: asked again, waited for when they left the
    bus, and named in the log when they stay silent on it."""

    def __init__(self, brains: Brains, tick: int, waits: Waits):
        self.brains, self.tick, self.waits = brains, tick, waits
        self.asked_at, self.said_at = time.monotonic(), None

    def ask_again(self, silent: list[int], requests: list[Sensors]) -> None:
        b = self.brains
        for k in silent:
            if not b.presences[k].alive:
                log.warning("%s lost at tick %d: waiting for it to come back", b.names[k], self.tick)
                b.lost_at.append(self.tick)
                with self.waits:  # Ctrl-C ends the run here, at once
                    wait_for_subscriber(b.sensors[k], b.waited_for[k], b.presences[k])
                log.info("%s back: continuing at tick %d", b.names[k], self.tick)
                self.asked_at, self.said_at = time.monotonic(), None
            b.sensors[k].put(requests[k])
        now = time.monotonic()
        if now - self.asked_at >= UNANSWERED_S and (self.said_at is None or now - self.said_at >= 60):
            self.said_at = now  # on the bus, yet silent: it refuses these sensors and says why, or it is compiling
            first = b.first_answer_at is None  # a brain's first answer waits for its kernels (compiled once a machine)
            log.warning(
                "%s on the bus but no answer to tick %d for %.0f s: %sits log says why (a brain "
                "refuses sensors that do not fit its circuit, parameter file or shard)",
                " and ".join(b.names[k] for k in silent),
                self.tick,
                now - self.asked_at,
                "on a first run on this machine a brain compiles its kernels (a minute or two); else " if first else "",
            )
