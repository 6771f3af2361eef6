"""The free-running (robot) brain: it ticks on its own clock (--clock Hz) with the latest sensor
reading and sends a Motor message only when an action fired (and a heartbeat at least every
HEARTBEAT_S), until an "end" of the robot's run or Ctrl-C. Its clock's lateness is kept as a
streaming histogram: the same memory after a minute or a week."""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import time
from typing import TYPE_CHECKING

import numpy as np

from services.bus import keys
from services.bus.schemas import Array, BusError, Control, Motor, Sensors
from services.bus.transport import Bus, wait_for_subscriber
from services.options import Parser, not_negative, positive

from .brain import check_sensors
from .checkpoint import save_weights
from .node import BrainNode, layout

if TYPE_CHECKING:  # the service module, which starts this one
    from .service import BrainConfig

log = logging.getLogger("spikinglab.brain")
HEARTBEAT_S = 0.05  # a motor message (an empty one if nothing fired) at least this often
CATCH_UP_S = 0.05  # a clock this far behind skips ahead instead of running the missed ticks
SPIN_S = 0.0003  # the clock sleeps until this long before a tick is due and spins the rest
CONTROL_EVERY = 100  # ticks between looks at the control key


def add_free_running_args(p: argparse.ArgumentParser) -> None:
    """The options of robot mode."""
    free = p.add_argument_group("free-running (robot)")
    free.add_argument(
        "--clock",
        type=not_negative,
        default=0,
        metavar="HZ",
        help="tick on this clock with the latest sensor reading, motor spikes as events "
        "(robot mode, e.g. 1000); default 0: lock-step with a world",
    )
    # these two without defaults here (free_running_options): with no --clock they are refused
    free.add_argument(
        "--stale-after",
        type=positive,
        help="seconds after which a reading no longer counts as sensed (default 0.5)",
    )
    free.add_argument(
        "--no-realtime",
        action="store_true",
        default=None,
        help="do not ask for real-time scheduling of the clock thread (asked by default; needs "
        "root or CAP_SYS_NICE on Linux, else the normal scheduler is used)",
    )


def free_running_options(p: Parser, args: argparse.Namespace) -> None:
    """The free-running brain's options refused in lock-step, and --checkpoint (the world's
    checkpoints, which a robot's run has none of) refused with --clock: each would be ignored."""
    p.mode_defaults(
        args,
        "--clock" if args.clock else "",
        {"--stale-after": (0.5, ("--clock",)), "--no-realtime": (False, ("--clock",)), "--checkpoint": (None, ("",))},
    )


class Lateness:
    """How late the clock's ticks came, as a histogram with bins RATIO apart from FLOOR_S to CEILING_S
    (quantiles within 0.5 %, a fixed 15 kB), and the exact maximum."""

    FLOOR_S, CEILING_S, RATIO = 1e-7, 10.0, 1.01

    def __init__(self):
        self.log_ratio = math.log(self.RATIO)
        self.counts = [0] * (int(math.log(self.CEILING_S / self.FLOOR_S) / self.log_ratio) + 2)
        self.total, self.max = 0, 0.0

    def add(self, seconds: float) -> None:
        """One tick `seconds` late (0 or less: on time, the first bin)."""
        k = 0 if seconds <= self.FLOOR_S else int(math.log(seconds / self.FLOOR_S) / self.log_ratio) + 1
        self.counts[min(k, len(self.counts) - 1)] += 1
        self.total += 1
        self.max = max(self.max, seconds)

    def quantile(self, q: float) -> float:
        """The q-quantile (0 to 1) in seconds: the geometric middle of its bin (0 for the first bin,
        the maximum for the last, never above the maximum); 0 before any tick."""
        rank, seen, last = q * (self.total - 1), 0, len(self.counts) - 1
        for k, count in enumerate(self.counts):
            seen += count
            if seen > rank:
                return (
                    0.0 if k == 0 else self.max if k == last else min(self.FLOOR_S * self.RATIO ** (k - 0.5), self.max)
                )
        return 0.0

    def stats_ms(self) -> dict:
        """The stats file's lateness keys, in milliseconds."""
        return {
            "late_ms_median": round(self.quantile(0.5) * 1000, 4),
            "late_ms_p99": round(self.quantile(0.99) * 1000, 4),
            "late_ms_max": round(self.max * 1000, 3),
        }


class Clock:
    """Ticks due at start + k / hz (no drift): wait() sleeps until shortly before the next one and
    spins the rest, because a plain sleep wakes up to ~0.1 ms late, more under load."""

    def __init__(self, hz: float):
        self.period = 1.0 / hz
        self.started = self.next_at = time.monotonic()
        self.lateness = Lateness()

    def wait(self) -> None:
        self.next_at += self.period
        behind = time.monotonic() - self.next_at
        if behind > CATCH_UP_S:  # stalled (stopped, starved): go on from now, no burst of old ticks
            log.warning("the clock stalled for %.2f s: %d ticks skipped", behind, int(behind / self.period))
            self.next_at = time.monotonic()
        gap = self.next_at - time.monotonic()
        if gap > SPIN_S:
            time.sleep(gap - SPIN_S)
        while time.monotonic() < self.next_at:
            pass
        self.lateness.add(time.monotonic() - self.next_at)


def realtime_clock() -> None:
    """SCHED_FIFO for this (the clock's) thread only: the kernel then runs it the moment its sleep
    ends instead of after the time slice of whatever else shares its core (zenoh's threads do). It
    sleeps most of each tick, so those threads still run."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        log.info("clock thread on real-time scheduling (SCHED_FIFO)")
    except (OSError, AttributeError) as e:
        log.info("clock thread on the normal scheduler (real-time not permitted: %s)", e)


class FreeRunning:
    """Robot mode on `bus`: one BrainNode, ticked by a Clock with the latest reading."""

    def __init__(self, config: BrainConfig, bus: Bus, node: BrainNode):
        self.config, self.bus, self.node = config, bus, node
        group = bus.group
        self.sensors = bus.inbox(keys.sensors(group), Sensors)
        self.control = bus.inbox(keys.control(group), Control)
        self.motor = bus.outbox(keys.motor(group))
        self.state = bus.outbox(keys.brain_state(group), lossy=True) if config.publish_state else None
        self.latest: Sensors | None = None  # the reading the brain senses
        self.latest_at = self.spoke_at = 0.0  # when it came, when the last Motor message went (monotonic)
        self.tick = 0
        bus.watch_others(lambda: f" at tick {self.tick} of run {node.run}" if node.run else "")

    def run(self) -> int:
        config = self.config
        log.info(
            "brain ready on group %s (%s), free-running at %g Hz; waiting for sensors",
            self.bus.group,
            self.bus.sender,
            config.clock,
        )
        first = self.first_reading()
        self.node.start(first)
        self.node.run = first.run
        nothing = np.full(first.values.shape, np.nan)
        if self.state is not None:
            wait_for_subscriber(self.state, "a recorder")
            self.state.put(layout(self.node.circuit, 0, self.node.run))
        if not config.no_realtime:
            realtime_clock()
        clock = Clock(config.clock)
        try:
            while not self.step(nothing):
                self.tick += 1
                clock.wait()
        except KeyboardInterrupt:
            pass
        self.finish(clock)
        return 0

    def first_reading(self) -> Sensors:
        """The first reading that fits the circuit: it tells the sensors and the agents."""
        while True:
            message = self.sensors.get(timeout=0.25)
            if not isinstance(message, Sensors):
                continue
            try:
                check_sensors(self.node.circuit, message.names)
            except ValueError as e:
                self.sensors.refuse(BusError(f"does not fit the circuit: {e}"))
                continue
            self.latest, self.latest_at = message, time.monotonic()
            return message

    def reading(self, now: float) -> Sensors | None:
        """The newest reading that fits the robot's run, or None while the last one is stale."""
        latest, message = self.latest, self.sensors.latest()  # only the newest reading counts
        assert latest is not None
        fresh = now - self.latest_at < self.config.stale_after
        if isinstance(message, Sensors):
            if message.names != latest.names or message.values.shape != latest.values.shape:
                self.sensors.refuse(
                    BusError(f"does not fit the run: {list(message.values.shape)} sensors of {list(message.names)}")
                )
            elif message.run != latest.run and fresh:  # a new run once the robot's has gone quiet
                self.sensors.refuse(BusError(f"another run: {message.run!r}, the robot's is {latest.run!r}"))
            else:
                if message.run != latest.run:
                    log.info("the robot's run is now %s (%s went quiet)", message.run, latest.run)
                self.latest, self.latest_at, fresh = message, now, True
        return self.latest if fresh else None

    def step(self, nothing: np.ndarray) -> bool:
        """One tick: sense, step, speak if an action fired (or to show it lives). True when the
        robot's run has ended."""
        now = time.monotonic()
        reading = self.reading(now)
        brain = self.node.brain
        assert brain is not None and self.latest is not None
        actions = brain.step(reading.values.numpy("values", "<f8", 2) if reading is not None else nothing)
        self.node.last_tick = self.tick
        if actions.any() or now - self.spoke_at > HEARTBEAT_S:  # silence would mean a stalled brain
            self.motor.put(
                Motor(
                    tick=self.tick,
                    names=brain.action_names,
                    actions=Array.of(actions),
                    run=self.latest.run,
                    reading=self.latest.tick,
                )
            )
            self.spoke_at = now
        if self.state is not None:
            self.node.keep_state()
            if self.node.batch.full:
                self.state.put(self.node.state_message())
        return self.tick % CONTROL_EVERY == 0 and self.ended()

    def ended(self) -> bool:
        """Whether an "end" of the robot's run came (an end of another run is refused)."""
        order = self.control.get(timeout=0)
        if not isinstance(order, Control) or self.latest is None:
            return False
        if order.run == self.latest.run:
            return True
        self.control.refuse(BusError(f"another run: end of run {order.run!r}, the robot's run is {self.latest.run!r}"))
        return False

    def finish(self, clock: Clock) -> None:
        """The last state batch, the stats (logged, and to --stats) and the weights (--save)."""
        config, node = self.config, self.node
        if self.state is not None:
            self.state.put(node.state_message(final=True))
        elapsed = time.monotonic() - clock.started
        stats = {
            "ticks": self.tick,
            "hz": round(self.tick / elapsed, 1),
            **clock.lateness.stats_ms(),
            "rejected_messages": self.bus.rejections(),
        }
        log.info(
            "free-running brain stopped after %d ticks: %.1f Hz, lateness median %.3f ms, p99 %.3f ms",
            self.tick,
            stats["hz"],
            stats["late_ms_median"],
            stats["late_ms_p99"],
        )
        if config.stats:
            config.stats.parent.mkdir(parents=True, exist_ok=True)
            config.stats.write_text(json.dumps(stats))
        if config.save and node.brain is not None:
            save_weights(config.save, node.brain.engine, node.circuit, tick=self.tick, say=True)
