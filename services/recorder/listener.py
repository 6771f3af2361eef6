"""The recorder's loop: a group's state messages into a Recorder, one file a run, until the run ends.

A message of another run is held (NEXT_RUN_HELD at most) while the run recorded may still go on;
once that run has been quiet for QUIET_S (cut short, or --forever), the next run gets a file of
its own. The recording ends when every stream that came has sent its final batch, END_GRACE after
the run's end at the latest, or when the world and the brain left without one.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

import rerun as rr

from services.bus.schemas import RUN_ID, BrainState, BusError, WorldState
from services.bus.transport import QUIET_S, Inbox, Presence

from .recorder import Recorder

log = logging.getLogger("spikinglab.recorder")
END_GRACE = 5.0  # seconds to wait after the run's end for the brain's last messages
LEFT_GRACE = 1.0  # seconds: what a service sent before it left may come after the news that it left
FLUSH_S = 0.5  # written to the file at least this often: a killed recorder loses about this much of the run
NEXT_RUN_HELD = 256  # messages of another run held while the run recorded may still go on (its map comes first)
STREAMS = {WorldState: "world", BrainState: "brain"}  # state streams by their names in Recorder.next_tick


class Listener:
    """What the recorder has of the group: the recording of the run now recorded, the messages of
    the run that follows it, and whether it is time to end. `step(message)` per inbox read."""

    def __init__(
        self,
        inbox: Inbox,
        watched: dict[str, Presence],
        rec: rr.RecordingStream,
        recorder: Recorder,
        out: Path,
        group: str,
        forever: bool,
        open_next: Callable[[Path, str], rr.RecordingStream],
    ):
        """`rec`, `recorder`, `out`: the first run's; `open_next(path, run id)`: a recording for
        a run that follows (it serves nothing itself: the first one's stream serves every run)."""
        self.inbox, self.watched, self.open_next = inbox, watched, open_next
        self.group, self.forever = group, forever
        self.rec, self.first_stream, self.recorder, self.out, self.current = rec, rec, recorder, out, out
        self.next_run: list = []  # messages of another run, held until the run recorded has gone quiet
        self.rejected, self.last_flush, self.ending = 0, time.monotonic(), None
        self.received, self.first_at = 0, time.monotonic()
        self.heard_at = time.monotonic()  # when the run recorded last sent a message that was recorded
        self.left_at: float | None = None  # when world and brain were first seen gone, the run not ended
        self.leaving: list[tuple[str, int]] = []  # (world or brain, tick seen) gone, its run's end not yet come

    def step(self, message) -> bool:
        """One read of the inbox (`message`, or None when none came): recorded, and everything
        around it seen to. True when the recording is over."""
        self.say_presence()
        if message is not None:
            self.take(message)
        self.say_left()
        # the run recorded has gone quiet: the next one, if the run recorded was cut short or --forever
        if (
            self.next_run
            and time.monotonic() - self.heard_at > QUIET_S
            and (self.forever or not self.recorder.world_done)
        ):
            self.start_next_run()
        self.say_rejections()
        if self.over():
            return True
        self.see_if_left()
        if time.monotonic() - self.last_flush > FLUSH_S:
            self.recorder.flush()
            self.last_flush = time.monotonic()
        return False

    def say_presence(self) -> None:
        """World and brain coming and going, as events of the recording."""
        for name, presence in self.watched.items():
            while not presence.events.empty():
                change, _ = presence.events.get()
                tick = max(self.recorder.last_tick, 0)  # the tick the recorder has got to: it can trail the run
                if change == "down":
                    self.leaving.append((name, tick))
                    continue
                self.say_left(came_back=name)
                self.recorder.event(f"{name} is on the bus (seen while recording tick {tick})", "INFO", tick)

    def say_left(self, came_back: str | None = None, at_end: bool = False) -> None:
        """Each departure seen, once it is known how it went: after the run's end for it (its final
        batch, which can come after the news that it left), or without it (WARN): it came back
        (`came_back`: its name), or the recording ends first (`at_end`)."""
        waiting = []
        for name, tick in self.leaving:
            ended = self.recorder.world_done if name == "world" else self.recorder.brain_done
            if ended or at_end or name == came_back:
                how = "" if ended else " before the run's end"
                text = f"{name} left the bus{how} (seen while recording tick {tick})"
                self.recorder.event(text, "INFO" if ended else "WARN", tick)
            else:
                waiting.append((name, tick))
        self.leaving = waiting

    def take(self, message) -> None:
        if self.received == 0:
            self.first_at = time.monotonic()
        self.received += 1
        try:
            self.record(message)
            self.heard_at = time.monotonic()
            # a world shard's final batch is not the world's: the recorder's join of them says when that came
            done = self.recorder.world_done or self.recorder.brain_done
            if done and not self.forever and self.ending is None:
                self.ending = time.monotonic() + END_GRACE
        except BusError as e:  # it does not fit the recording: refused whole, counted
            if (
                self.recorder.run is not None
                and message.run != self.recorder.run
                and RUN_ID.fullmatch(message.run)
                and len(self.next_run) < NEXT_RUN_HELD
            ):
                self.next_run.append(message)  # perhaps the next run: it waits for this one to go quiet
            else:
                self.inbox.refuse(e, f"({type(message).__name__} of tick {message.tick})")

    def record(self, message) -> None:
        """Into the recording, saying in the log when each state stream of the run first comes in
        (state messages are lossy on the bus: a late recorder may miss the first ones)."""
        stream = STREAMS.get(type(message))
        new = stream is not None and stream not in self.recorder.next_tick
        self.recorder.on(message)
        if new and stream in self.recorder.next_tick:  # a world shard's slice: once the state is joined
            log.info("the %s's state comes in from tick %d", stream, message.tick)

    def start_next_run(self) -> None:
        """The run recorded is closed; the run of the messages held gets a file and a Recorder."""
        self.say_left(at_end=True)
        self.recorder.close()
        if self.rec is not self.first_stream:
            self.rec.flush()
            self.rec.disconnect()
        run_id = self.next_run[0].run
        path = self.out.with_name(f"{self.out.stem}-{run_id}{self.out.suffix}")
        log.info(
            "run %s: recorded to %s (%s); run %s starts: recording it to %s",
            self.recorder.run,
            self.current,
            self.recorder.ticks_held(),
            run_id,
            path,
        )
        self.rec = self.open_next(path, run_id)
        self.recorder = Recorder(self.rec, detail=self.recorder.detail, flush_every=self.recorder.flush_every)
        self.current, self.ending = path, None
        self.recorder.event(f"recorder on group {self.group}: run {run_id} follows another run, writing {path}")
        for held in self.next_run:
            try:
                self.record(held)
            except BusError as e:
                self.inbox.refuse(e, f"({type(held).__name__} of tick {held.tick})")
        self.next_run, self.heard_at = [], time.monotonic()

    def say_rejections(self) -> None:
        inbox = self.inbox
        if inbox.rejected_total + inbox.dropped != self.rejected:
            reasons = ", ".join(f"{n} x {r} on {k}" for (k, r), n in inbox.counts.items())
            self.rejected = inbox.rejected_total + inbox.dropped
            self.recorder.event(f"rejected or dropped messages so far: {self.rejected} ({reasons})", "WARN")

    def over(self) -> bool:
        """The run is over when every stream that came has sent its final batch (the world's and
        the brain's come on different links, in either order), or END_GRACE after its end."""
        r = self.recorder
        return bool(
            self.ending
            and (
                (r.world_done or r.agents == 0)
                and (r.brain_done or r.spike_counts is None)
                or time.monotonic() > self.ending
            )
        )

    def see_if_left(self) -> None:
        """World and brain both gone without the run's end, LEFT_GRACE on (their final batches may
        still be on the way): what came is written, END_GRACE on."""
        seen = [presence for presence in self.watched.values() if presence.seen]
        if not seen or any(p.alive for p in seen) or self.forever or self.ending is not None:
            self.left_at = None
            return
        now = time.monotonic()
        self.left_at = self.left_at or now
        if now - self.left_at < LEFT_GRACE:
            return
        self.ending = now + END_GRACE
        self.recorder.event(
            f"the {' and the '.join(n for n, p in self.watched.items() if p.seen)} left without the "
            f"run's end: the recording ends at tick {max(self.recorder.last_tick, 0)}",
            "WARN",
        )
        log.warning("the services recorded left without the run's end: ending the recording in %.0f s", END_GRACE)

    def close(self) -> None:
        """Messages still held refused (they came after the run recorded ended), everything written."""
        for held in self.next_run:
            self.inbox.refuse(
                BusError(
                    f"another run: {held.run!r}, after the run recorded ended (--forever records the runs that follow)"
                ),
                f"({type(held).__name__} of tick {held.tick})",
            )
        silent = self.recorder.shards.silent()
        if silent:
            text = (
                f"world shard {', '.join(silent)} sent no state: the population's ticks are joined from every "
                f"shard's, so none were recorded (--publish-state on every world shard, docs/shards.md)"
            )
            self.recorder.event(text, "WARN")
            log.warning("%s", text)
        self.say_left(at_end=True)
        self.recorder.close()
        for stream in [self.rec] if self.rec is self.first_stream else [self.rec, self.first_stream]:
            stream.flush()
            stream.disconnect()
