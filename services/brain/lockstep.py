"""The brain in lock-step with a world, run after run: each Sensors message answered by one Motor
message; on Control "end" the brain saves its weights (--save) and its stats (--stats), then serves
the next run (or exits, --once); a sharded world's end once every shard of it has stopped. A run
that stops without its end keeps its learning so far."""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from services.bus import keys
from services.bus.schemas import BusError, Control, Sensors
from services.bus.transport import Bus, wait_for_subscriber

from .checkpoint import save_weights
from .node import BrainNode, layout

if TYPE_CHECKING:  # the service module, which starts this one
    from .service import BrainConfig

log = logging.getLogger("spikinglab.brain")
GONE_S = 15.0  # on a router without its world (which kept no checkpoint) this long: a --once brain ends
# A world shard's -done token and its leaving reach the brain on two watches, in either order (one
# that ends its ticks after the lead's end says it is done and leaves within a millisecond): a shard
# seen gone with no -done token is given this long for the token to come before it counts as lost.
DONE_GRACE_S = 1.0


class LockStep:
    """A brain serving worlds on `bus`, a fresh BrainNode (`new_node()`) for each run; for a sharded
    world (world --shard I/N), one for the piece of its agents each world shard sends."""

    def __init__(self, config: BrainConfig, bus: Bus, new_node: Callable[[], BrainNode]):
        self.config, self.bus, self.new_node = config, bus, new_node
        self.nodes: dict[int, BrainNode] = {}  # by the first agent of the piece each serves
        self.idle = new_node()  # what `node` is before a run's first piece
        self.kept: tuple | None = None  # (run, ticks) whose learning was saved when the run stopped without its end
        self.ending: Control | None = None  # the end of the run served, held until it is due (due_end)
        self.heard_at = time.monotonic()  # when the last sensors came
        self.router_since: float | None = None  # on a router, its world gone, since (world_gone_for_good)
        self.exit_code = 0  # --once: 1 where a world shard of the run served was lost
        self.stats_written: dict | None = None  # what the --stats file holds, once written
        group = bus.group
        self.sensors = bus.inbox(keys.sensors(group, config.shard), Sensors)
        self.control = bus.inbox(keys.control(group), Control)
        self.motor = bus.outbox(keys.motor(group))
        self.state = bus.outbox(keys.brain_state(group), lossy=True) if config.publish_state else None
        # every world shard of the run, the lead first: one of them still on the bus may still send,
        # so a pause in its sensors is not the run's stop (its learning is kept once, when all have gone)
        shards = config.world_shards
        self.worlds = [bus.presence(keys.world_service((i, shards))) for i in range(1, shards + 1)]
        self.done = [bus.presence(keys.world_done((i, shards))) for i in range(2, shards + 1)]
        bus.watch_others(self.where)

    @property
    def node(self) -> BrainNode:
        """The node of the first piece served (the only one unless the world is sharded)."""
        return self.nodes[min(self.nodes)] if self.nodes else self.idle

    def world_alive(self) -> bool:
        """Whether the world of the run served, or a shard of it, is on the bus."""
        return any(world.alive for world in self.worlds)

    def world_gone_for_good(self) -> bool:
        """Whether the world of the run served (every shard of it) left the bus and cannot come back
        to go on: it kept no checkpoint of the run, and this brain has been on a router without it
        for GONE_S (a gateway's run, with no world seen, never is). A world behind a router that
        died comes back with the router, so the time counts from when this brain last reached a
        router; peers only (the world its link), it may come back too."""
        node = self.node
        stopped = node.run and self.kept == self.progress()  # its learning kept: it stopped without its end
        seen = any(world.seen for world in self.worlds)
        if self.world_alive() or not seen or not stopped or node.kept_by_world == node.run:
            self.router_since = None
            return False
        if not list(self.bus.session.info.routers_zid()):
            self.router_since = None
            return False
        if self.router_since is None:
            self.router_since = time.monotonic()
        return time.monotonic() - self.router_since >= GONE_S

    def where(self) -> str:
        """The tick this brain has reached, for the news of others joining or leaving."""
        return f" at tick {self.node.last_tick + 1} of run {self.node.run}" if self.node.run else ""

    def progress(self) -> tuple:
        """The run served and the last tick of each piece."""
        return self.node.run, tuple(self.nodes[k].last_tick for k in sorted(self.nodes))

    def unsaved(self) -> bool:
        """Whether there is learning of a run that has not ended, not kept yet (none before the
        first step: an interrupt waits for the compile that builds the brain, then lands there)."""
        stepped = any(n.brain is not None and n.last_tick >= 0 for n in self.nodes.values())
        return stepped and self.kept != self.progress()

    def starts_run(self, message: Sensors) -> bool:
        """Whether `message` starts a new run: every node's run has gone quiet (BrainNode.starts_run)."""
        return bool(self.nodes) and all(n.brain is not None and n.starts_run(message) for n in self.nodes.values())

    def node_for(self, message: Sensors, new_run: bool) -> BrainNode:
        """The node serving the piece `message` starts at. Sensors that start a new run (`new_run`)
        start it with no node of the last; another piece of the run served, from another of
        --world-shards N world shards, gets a node of its own (N at most); any other message goes
        to the node served, whose answer says why it does not fit."""
        if new_run:
            if self.unsaved():
                self.keep_learning(f"run {message.run} starts before it ended")
            self.nodes = {}
        node = self.nodes.get(message.first)
        if node is not None:
            return node
        if self.nodes and (message.run != self.node.run or len(self.nodes) >= self.config.world_shards):
            return self.node
        if not self.nodes:  # the run's first piece: which world shards are seen, and finish, from now on
            for presence in (*self.worlds, *self.done):
                presence.seen_from_now()
        return self.nodes.setdefault(message.first, self.new_node())

    def run(self) -> int:
        shard = self.config.shard
        log.info(
            "brain ready on group %s (%s)%s",
            self.bus.group,
            self.bus.sender,
            f", shard {shard[0]} of {shard[1]}" if shard[1] > 1 else "",
        )
        try:
            while True:
                message = self.sensors.get(timeout=0.25)
                if isinstance(message, Sensors):
                    new_run = self.starts_run(message)  # asked once: the answer changes as time passes
                    if new_run and self.ending is not None and self.finish_run(self.ending):
                        return self.exit_code  # the run served had its end, and --once serves no other
                    self.serve(message, new_run)
                if self.take_orders():
                    return self.exit_code
                if message is None and self.unsaved() and not self.world_alive():  # gone without an end
                    self.keep_learning("its world left the bus")
                if self.config.once and self.world_gone_for_good():
                    log.error(
                        "run %s cannot go on: its world left the bus, kept no checkpoint of it to resume from "
                        "and has not come back in %.0f s; --once ends here",
                        self.node.run,
                        GONE_S,
                    )
                    return 1
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM mid-run: the learning so far is kept
            if self.unsaved():  # an end that came while the brain was busy (a kernel compiling) is taken
                self.read_orders()
            if self.ending is not None:  # its end came: the wait for a world shard to stop is cut short
                self.end_run(self.ending)
            elif self.unsaved():
                self.keep_learning("the brain was interrupted")
            raise
        finally:  # stopped before a run's end, its rejections would be in the log alone
            self.stats_on_the_way_out()

    def serve(self, message: Sensors, new_run: bool) -> None:
        """Answer one Sensors message: the Motor first, then the recorder's share."""
        self.heard_at = time.monotonic()
        try:
            node, state = self.node_for(message, new_run), self.state
            if state is not None and node.last_tick < 0:
                wait_for_subscriber(state, "a recorder")
                state.put(layout(node.circuit, message.tick, message.run))
            answer = node.answer(message)
        except BusError as e:
            self.sensors.refuse(e, f"(tick {message.tick})")
            if message.first in self.nodes and self.nodes[message.first].brain is None:
                del self.nodes[message.first]  # refused as it came: no node kept for it
            return
        if answer is not None:
            self.motor.put(answer)  # first: the world waits for it; the recorder does not
            if state is not None and node.stepped:
                node.keep_state()
                if node.batch.full:
                    state.put(node.state_message())

    def take_orders(self) -> bool:
        """Every control message waiting; an "end" of the run served ends it once it is due
        (due_end). True when this brain is done (--once)."""
        self.read_orders()
        return bool((due := self.due_end()) and self.finish_run(due))

    def read_orders(self) -> None:
        """Every control message waiting (a flood on the control key must not pile up while the run
        goes on); the first "end" of the run served is held in `ending`."""
        while isinstance(order := self.control.get(timeout=0), Control):
            try:
                for node in list(self.nodes.values()) or [self.node]:
                    node.ends(order)
            except BusError as e:
                self.control.refuse(e)
                continue
            self.ending = self.ending or order  # the first: a replay or forgery after it changes nothing

    def due_end(self) -> Control | None:
        """The end of the run served if it ends the run now. A sharded world's waits until every
        other shard has stopped (its -done token) or left the bus: the lead's end names its own
        tick, and the other shards, not in step with it, each stop at their next; until then their
        pieces are answered, so that each shard gets the answers to the ticks it steps (an end forged
        mid-run is held as long; one past the lead's tick ends the lead's piece as it would end one
        world's run). A shard on the bus that sends nothing for GONE_S (stuck, or a forged token)
        holds it no longer."""
        if self.ending is None or self.config.world_shards == 1:
            return self.ending
        stepping = any(world.alive and not done.alive for world, done in zip(self.worlds[1:], self.done))
        if stepping and time.monotonic() - self.heard_at < GONE_S:
            return None
        return self.ending

    def finish_run(self, order: Control) -> bool:
        """End the run served at `order`; True when this brain is done (--once), with exit_code 1
        where a world shard of the run was lost."""
        lost = self.end_run(order)
        self.ending = None  # only now: a SIGTERM while the end is saved saves it again (run's except)
        if self.config.once:
            if lost:
                log.error("run %s has no whole result (%s); --once ends here", order.run, "; ".join(lost))
                self.exit_code = 1
            return True
        self.nodes = {}
        return False

    def lost_shards(self) -> list[str]:
        """What became of each world shard of the run served (but the lead, which ends it) that left
        the bus before it finished its ticks: gone, and no -done token of this run seen, nor within
        DONE_GRACE_S (each holds its token until the lead's end; one gone before this brain's first
        piece of the run counts too, and one never seen may be no shard of the world's)."""
        deadline = time.monotonic() + DONE_GRACE_S
        gone = [(w, d) for w, d in zip(self.worlds[1:], self.done) if not w.alive and not d.seen]
        lost = [w for w, d in gone if not d.wait_seen(max(0.0, deadline - time.monotonic()))]
        return [
            f"{w.service} left the bus before the end of its ticks"
            if w.seen  # else gone before this brain came, or no such shard
            else f"{w.service} was never on the bus (--world-shards {self.config.world_shards}: the world's?)"
            for w in lost
        ]

    def end_run(self, order: Control) -> list[str]:
        """The run ended: the last state batch with the final weights, the stats, the weights saved;
        where a world shard of it was lost, they are kept as a run that stopped without its end (not
        saved to --save, which holds whole runs). The world shards lost."""
        config, node = self.config, self.node
        if self.state is not None and node.brain is not None:
            self.state.put(node.state_message(final=True))
        pieces = ""
        if config.world_shards > 1:  # the end's tick is the lead shard's; the others stopped at their own
            ticks = ", ".join(map(str, self.progress()[1]))
            pieces = f" (world shard 1's; the last tick of each piece served: {ticks})"
        log.info("run ended at tick %d%s; rejected messages: %s", order.tick, pieces, self.bus.rejections() or "none")
        self.write_stats(node.last_tick + 1)
        lost = self.lost_shards()
        if lost:
            self.keep_learning("; ".join(lost), order.tick)
        elif config.save and node.brain is not None:
            save_weights(config.save, self.weights(), node.circuit, tick=order.tick, say=True)
        return lost

    def write_stats(self, ticks: int) -> None:
        """The --stats file: the run's ticks and every message rejected so far (unless it holds them)."""
        stats = {"ticks": ticks, "rejected_messages": self.bus.rejections()}
        if self.config.stats and stats != self.stats_written:
            self.config.stats.parent.mkdir(parents=True, exist_ok=True)
            self.config.stats.write_text(json.dumps(stats))
            self.stats_written = stats

    def stats_on_the_way_out(self) -> None:
        """The stats as the brain leaves, if it has any: the ticks of a run under way (else of the
        last run written, whose file is not overwritten with an idle brain's 0) and the rejections."""
        ticks = self.node.last_tick + 1 if self.nodes else (self.stats_written or {"ticks": 0})["ticks"]
        if ticks or self.bus.rejections():
            self.write_stats(ticks)

    def weights(self) -> np.ndarray:
        """The weights of every agent served, pieces in the population's order."""
        return np.concatenate([self.nodes[k].running.engine.get_weights() for k in sorted(self.nodes)])

    def keep_learning(self, why: str, ended_at: int | None = None) -> None:
        """A run stopped without its end, or ended (at tick `ended_at`) with a world shard lost, for
        `why`: its weights so far are saved beside --save, never lost to the next run."""
        save, node = self.config.save, self.node
        what = f"run {node.run} " + (
            f"ended at tick {ended_at} without a whole result"
            if ended_at is not None
            else f"stopped at tick {node.last_tick + 1} without its end"
        )
        if not save:
            self.kept = self.progress()
            log.warning("%s (%s); its weights are not saved (no --save)", what, why)
            return
        path = save.with_name(f"{save.stem}-{node.run}-tick{node.last_tick + 1}.npz")
        save_weights(path, self.weights(), node.circuit, tick=node.last_tick + 1)
        # kept only now: a SIGTERM during the save (the run ending as its world is lost) saves again
        self.kept = self.progress()
        log.warning("%s (%s): its weights so far saved to %s", what, why, path)
