"""The EV3 gateway: `spikinglab gateway` / `python -m services.ev3_gateway`.

Reads:  spikinglab/<group>/motor (Motor events of a free-running brain), the brain's liveliness
Writes: spikinglab/<group>/sensors (every reading), liveliness spikinglab/<group>/alive/gateway

It polls the robot as fast as the link allows and publishes every reading, mapped as in the
paper: colour black / red / green -> the three smells (fed 0: the patch is right under the
sensor; other colours are floor), ultrasonic below 5 cm -> pain, touch -> reward. Motor events
become timed commands: MOVE -> both motors forward for 500 ms, ROTATE -> spin for 100 ms.

Busy motors: a command replaces whatever the motors are doing, with its own full duration (a
repeated MOVE extends the walk); if ROTATE and MOVE come in the same tick, ROTATE wins.
Safety (MotorRules): motor messages are followed only while a brain's liveliness token is on the
bus and only for this run; the free-running brain speaks at least every 50 ms, so the motors stop
when its token goes, when it was not heard for --motor-timeout (200 ms: stalled, or the link to it
broken), and when no motor command came within --motor-timeout after the last one ended. A
command answering a reading older than --max-command-age (a brain catching up after a stall) is
dropped and counted. A dying thread stops the gateway and its motors. A broken robot link is
reported and retried every second; the brain keeps running meanwhile. A link this machine cannot
make (no libusb for USB, no Bluetooth sockets in this Python) is refused before the bus: no retry
would bring it.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.bus import keys
from services.bus.config import BusConfig, Session, add_bus_args
from services.bus.schemas import Array, BusError, Control, Motor, Sensors, new_run_id
from services.bus.transport import Bus
from services.options import Parser, at_least, not_negative, number, output_file, positive
from services.runtime import service_main
from services.vocabulary import INSECT_SENSORS

from .backends import (
    BLACK,
    GREEN,
    RED,
    EV3Backend,
    LinkUnavailable,
    Reading,
    RobotLinkError,
    SimBackend,
    Wiring,
)

log = logging.getLogger("spikinglab.gateway")
READINGS_KEPT = 1 << 16  # publication times of the last readings (seconds' worth at any poll rate)
SMELL_OF_COLOUR = {BLACK: "smell_black", RED: "smell_red", GREEN: "smell_green"}


def parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="spikinglab gateway",
        description="The robot's side of the bus.",
        together=[lambda args: one_backends_options(p, args), robot_options_fit],
    )
    p.add_argument("--backend", choices=("ev3", "sim"), default="ev3", help="a real EV3 (default) or a simulated one")
    # each backend's options without defaults here (one_backends_options)
    robot = p.add_argument_group("EV3")
    robot.add_argument("--protocol", choices=("WiFi", "USB", "Bluetooth"), help="the link to the brick (default WiFi)")
    robot.add_argument(
        "--host",
        type=mac_address,
        help="the brick's MAC address, e.g. 00:16:53:42:2B:99 (Bluetooth: required; WiFi/USB: picks one of several)",
    )
    w = Wiring()
    for option, default in (
        ("--touch-port", w.touch),
        ("--colour-port", w.colour),
        ("--ultrasonic-port", w.ultrasonic),
    ):
        robot.add_argument(option, type=int, choices=range(1, 5), help=f"1-4 (default {default})")
    robot.add_argument("--motors", help=f"the two drive motor ports (default {w.motors})")
    robot.add_argument("--speed", type=int, help=f"forward speed, -100..100 (default {w.speed})")
    robot.add_argument("--spin-speed", type=int, help=f"spin speed, 0..100 (default {w.spin_speed})")
    sim = p.add_argument_group("simulated EV3")
    sim.add_argument("--sim-seed", type=at_least(0), help="the simulated world's seed (default 0)")
    sim.add_argument(
        "--sim-map", type=Path, help="the floor: a map file, as the world's --map (default: the paper's floor)"
    )
    sim.add_argument("--sim-patch-cm", type=positive, help="the floor's squares (default 30 cm)")
    sim.add_argument(
        "--sim-object-cm",
        type=positive,
        help="the objects in the centre of black and red squares (default 15 cm)",
    )
    sim.add_argument("--link-ms", type=not_negative, help="simulated link round trip (default 5 ms)")
    add_safety_args(p)
    p.add_argument(
        "--max-polls",
        type=not_negative,
        default=0,
        metavar="PER_S",
        help="poll at most this often (default 0: as fast as the link allows)",
    )
    p.add_argument(
        "--duration",
        type=not_negative,
        default=0,
        help="stop this many seconds after the first reading is published (default 0: run until Ctrl-C)",
    )
    p.add_argument(
        "--stats",
        type=output_file,
        help="write polls, commands, stops, link losses and the times of collisions here (JSON) at the end",
    )
    add_bus_args(p)
    return p


def mac_address(text: str) -> str:
    """--host: a MAC address, as ev3-dc matches a brick's (six pairs of hex digits, colons between)."""
    if not re.fullmatch(r"[0-9A-Fa-f]{2}(:[0-9A-Fa-f]{2}){5}", text):
        raise argparse.ArgumentTypeError(f"expected the brick's MAC address, e.g. 00:16:53:42:2B:99; got {text!r}")
    return text.upper()


def one_backends_options(p: Parser, args: argparse.Namespace) -> None:
    """An option of one backend given with the other is refused (it would be ignored); each left out
    takes its default here."""
    w = Wiring()
    ev3 = {
        "--protocol": "WiFi",
        "--host": None,
        "--touch-port": w.touch,
        "--colour-port": w.colour,
        "--ultrasonic-port": w.ultrasonic,
        "--motors": w.motors,
        "--speed": w.speed,
        "--spin-speed": w.spin_speed,
    }
    sim = {"--sim-seed": 0, "--sim-map": None, "--sim-patch-cm": 30.0, "--sim-object-cm": 15.0, "--link-ms": 5.0}
    p.mode_defaults(
        args,
        "--backend sim" if args.backend == "sim" else "",
        {
            **{option: (default, ("",)) for option, default in ev3.items()},
            **{option: (default, ("--backend sim",)) for option, default in sim.items()},
        },
    )


def robot_options_fit(args: argparse.Namespace) -> None:
    """The EV3 options checked together before anything starts (ValueError naming the option)."""
    if args.protocol == "Bluetooth" and not args.host:
        raise ValueError("--protocol Bluetooth needs --host, the brick's MAC address")
    wiring_of(args)


def wiring_of(config) -> Wiring:
    """The EV3's ports and speeds from the gateway's options (ValueError naming a wrong one)."""
    return Wiring(
        touch=config.touch_port,
        colour=config.colour_port,
        ultrasonic=config.ultrasonic_port,
        motors=config.motors,
        speed=config.speed,
        spin_speed=config.spin_speed,
    )


def add_safety_args(p: argparse.ArgumentParser) -> None:
    """How spikes become motor commands, and when the motors stop."""
    m = p.add_argument_group("mapping and safety")
    m.add_argument(
        "--move-ms",
        type=at_least(1),  # 0 would be "until stopped" to the brick
        default=500,
        help="forward time per MOVE spike (default 500)",
    )
    m.add_argument("--spin-ms", type=at_least(1), default=100, help="spin time per ROTATE spike (default 100)")
    m.add_argument("--pain-below-cm", type=not_negative, default=5.0, help="ultrasonic distance that hurts (default 5)")
    m.add_argument(
        "--contact-value",
        type=number,
        default=0.0,
        help="value fed for pain and reward (default 0: a spike in the tick it is read)",
    )
    m.add_argument(
        "--motor-timeout",
        type=positive,
        default=0.2,
        help="stop when the brain was not heard, or no command came after the last one ended, for this "
        "long (default 0.2 s: with the brain heard every 50 ms, a stall stops the motors within "
        "250 ms)",
    )
    m.add_argument(
        "--max-command-age",
        type=positive,
        default=0.2,
        help="drop a motor command that answers a reading older than this (default 0.2 s): a brain "
        "that stalled sends no backlog",
    )


@dataclass(frozen=True)
class GatewayConfig:
    """The gateway's options (parser()), typed: what run() and its parts take."""

    backend: str
    protocol: str  # the EV3's
    host: str | None
    touch_port: int
    colour_port: int
    ultrasonic_port: int
    motors: str
    speed: int
    spin_speed: int
    sim_seed: int  # the simulated EV3's
    sim_map: Path | None
    sim_patch_cm: float
    sim_object_cm: float
    link_ms: float
    move_ms: int  # mapping and safety
    spin_ms: int
    pain_below_cm: float
    contact_value: float
    motor_timeout: float
    max_command_age: float
    max_polls: float
    duration: float
    stats: Path | None
    bus: BusConfig


def sensor_values(reading: Reading, pain_below_cm: float, contact: float) -> np.ndarray:
    """One row of the insect's sensors (NaN: nothing) from a robot reading."""
    values = np.full((1, len(INSECT_SENSORS)), np.nan)
    smell = SMELL_OF_COLOUR.get(reading.colour)
    if smell:
        values[0, INSECT_SENSORS.index(smell)] = 0.0  # the patch is under the sensor
    if reading.distance_cm < pain_below_cm:
        values[0, INSECT_SENSORS.index("pain")] = contact
    if reading.touch:
        values[0, INSECT_SENSORS.index("reward")] = contact
    return values


@dataclass(frozen=True)
class MotorCall:
    """One backend call the gateway is to make: spin(ms, 1), forward(ms) or stop(); why: for the log."""

    call: str
    args: tuple = ()
    why: str = ""

    @property
    def seconds(self) -> float:
        return self.args[0] / 1000 if self.args else 0.0


class MotorRules:
    """The motor and safety rules, without the bus or the robot: told the time, whether a brain is
    on the bus and the actions of a motor message (or none), they say which call to make.

    The free-running brain speaks at least every HEARTBEAT_S (an empty motor message when nothing
    fired), so silence means a stalled brain, a broken link to it or a dead motor thread: the
    motors stop `timeout_s` after the brain was last heard, mid-command or not."""

    def __init__(self, move_ms: int, spin_ms: int, timeout_s: float):
        self.move_ms, self.spin_ms, self.timeout_s = move_ms, spin_ms, timeout_s
        self.brain_alive = False
        self.busy_until = 0.0  # when the running motor command ends
        self.heard_at = 0.0  # when the brain's last motor message (an empty one too) came
        self.stopped = True  # no motor command is running (or it was stopped)

    def decide(self, now: float, brain_alive: bool, actions: dict | None) -> MotorCall | None:
        if brain_alive != self.brain_alive:  # the log has it from the bus (watch_others), with the polls so far
            self.brain_alive = brain_alive
            if not brain_alive:
                return MotorCall("stop", why="the brain's liveliness token is gone")
        if actions is not None:
            if not brain_alive:  # nobody we know sent it
                return None
            self.heard_at = now
            if actions.get("rotate"):
                return MotorCall("spin", (self.spin_ms, 1))
            if actions.get("move"):
                return MotorCall("forward", (self.move_ms,))
            return None
        if self.stopped:
            return None
        if now > self.heard_at + self.timeout_s:
            return MotorCall("stop", why=f"no word from the brain for {self.timeout_s * 1000:.0f} ms")
        if now > self.busy_until + self.timeout_s:
            return MotorCall("stop", why=f"no motor command within {self.timeout_s * 1000:.0f} ms after the last ended")
        return None

    def made(self, call: MotorCall, now: float) -> None:
        """`call` reached the robot at `now`."""
        self.stopped = call.call == "stop"
        self.busy_until = 0.0 if self.stopped else now + call.seconds


def motor_actions(message: Motor, run: str) -> dict:
    """The robot's actions by name; BusError when the message is not for this run's one robot."""
    actions = message.actions.numpy("actions", "|u1", 2)
    if message.run != run:
        raise BusError(f"another run: motor for run {message.run!r}, the robot's run is {run!r}")
    if actions.shape != (1, len(message.names)):
        raise BusError(
            f"does not fit the run: actions of shape {list(actions.shape)}, a robot takes (1, {len(message.names)})"
        )
    return dict(zip(message.names, actions[0].tolist()))


def staleness(published: np.ndarray, polls: int, reading: int, now: float, max_age: float) -> str | None:
    """How old reading `reading` is, where older than `max_age` seconds; None where fresh enough (or
    negative: a command that answers no reading). `published`: the publication times of the last
    len(published) of `polls` readings, reading k at k % len(published)."""
    if reading < 0:
        return None
    back = polls - reading
    if back > len(published):  # its time is no longer kept: seconds old at any poll rate
        return f"{back} readings back"
    age = now - published[reading % len(published)]
    return None if age <= max_age else f"{age * 1000:.0f} ms old"


class Gateway:
    """The robot side: poll and publish in the calling thread, motor commands and safety in another."""

    def __init__(self, backend, bus: Bus, config: GatewayConfig):
        self.backend, self.bus, self.config = backend, bus, config
        self.sensors = bus.outbox(keys.sensors(bus.group))
        self.motor = bus.inbox(keys.motor(bus.group), Motor)
        self.brain = bus.presence("brain")
        self.lock = threading.Lock()  # one backend call at a time (the link is one socket)
        self.linked = threading.Event()
        self.done = threading.Event()
        self.rules = MotorRules(config.move_ms, config.spin_ms, config.motor_timeout)
        self.run_id = new_run_id()  # the brain's motor messages answer readings of this run
        self.started = time.monotonic()
        self.driven = False  # a brain's motor message was followed
        self.ends_at = math.inf  # --duration: counted from the first reading published
        self.published = np.zeros(READINGS_KEPT)  # when reading k was published, at k % READINGS_KEPT
        self.stats = {
            "polls": 0,
            "commands": 0,
            "safety_stops": 0,
            "stale_commands": 0,
            "link_losses": 0,
            "rejected_messages": {},
            "collisions": [],
        }

    def call(self, what: str, *args) -> bool:
        """A backend call under the lock; a link failure is noted for the poll loop to repair."""
        if not self.linked.is_set():
            return False
        try:
            with self.lock:
                getattr(self.backend, what)(*args)
            return True
        except RobotLinkError as e:
            self.link_lost(e)
            return False

    def link_lost(self, error: Exception) -> None:
        if self.linked.is_set():
            self.linked.clear()
            self.stats["link_losses"] += 1
            log.warning("robot link lost: %s; reconnecting", error)

    def connect(self) -> None:
        """(Re)connect, trying every second, until linked or done; a failed try is said every 10 s."""
        began, said = time.monotonic(), -math.inf
        if not self.stats["link_losses"] and (searching := self.backend.searching()):
            log.info("looking for the robot: %s", searching)
        while not self.done.is_set():
            try:
                if not self.try_link():
                    return
                self.linked.set()
                again = f" again after {time.monotonic() - began:.0f} s" if self.stats["link_losses"] else ""
                log.info("robot linked%s", again)
                return
            except RobotLinkError as e:
                if time.monotonic() - said >= 10:
                    said = time.monotonic()
                    log.warning("%s (retrying every second)", e)
                self.done.wait(1.0)

    def try_link(self) -> bool:
        """One try at the link; False when the gateway was told to end before it was over.

        The try runs in a thread of its own, as it can wait seconds deaf to signals (ev3-dc's WiFi
        listens 10 s for the brick's beacon): Ctrl-C and SIGTERM end the gateway meanwhile, and the
        try, a daemon thread left holding the lock, goes with the process."""
        outcome: list[BaseException | None] = []

        def attempt() -> None:
            try:
                with self.lock:
                    self.backend.close()
                    self.backend.connect()
                outcome.append(None)
            except BaseException as e:  # raised in the gateway's thread, as if it had tried itself
                outcome.append(e)

        threading.Thread(target=attempt, name="robot link", daemon=True).start()
        while not outcome:
            if self.done.wait(0.05):
                return False
        if outcome[0] is not None:
            raise outcome[0]
        return True

    def count_collision(self, reading: Reading, touching: bool) -> bool:
        """The paper's collision on the robot: the ultrasonic distance below --pain-below-cm. Each
        is noted as [start, end] in seconds since the start, to see learning on the robot."""
        now_touching = reading.distance_cm < self.config.pain_below_cm
        if now_touching != touching:
            at = round(reading.at - self.started, 3)
            if now_touching:
                self.stats["collisions"].append([at, None])
            else:
                self.stats["collisions"][-1][1] = at
        return now_touching

    def poll(self) -> None:
        tick = 0
        names = INSECT_SENSORS
        config = self.config
        interval = 1.0 / config.max_polls if config.max_polls else 0.0
        next_at = self.started = time.monotonic()
        touching = False
        while not self.done.is_set() and time.monotonic() < self.ends_at:
            if interval:
                next_at += interval
                time.sleep(max(0.0, next_at - time.monotonic()))
            if not self.linked.is_set():
                self.connect()
                continue
            try:
                with self.lock:
                    reading = self.backend.read()
            except RobotLinkError as e:
                self.link_lost(e)
                continue
            touching = self.count_collision(reading, touching)
            self.published[tick % READINGS_KEPT] = time.monotonic()
            self.stats["polls"] = tick + 1  # before the brain can answer it
            self.sensors.put(
                Sensors(
                    tick=tick,
                    names=names,
                    run=self.run_id,
                    values=Array.of(sensor_values(reading, config.pain_below_cm, config.contact_value)),
                )
            )
            if tick == 0:
                self.first_reading_out()
            tick += 1

    def first_reading_out(self) -> None:
        """--duration counts from here, when the robot is linked and the gateway under way (not from
        the process's start: the simulated floor, the session and the link take their time)."""
        duration = self.config.duration
        if duration:
            self.ends_at = time.monotonic() + duration
        log.info("first reading published%s", f"; ending in {duration:g} s" if duration else "")

    def commands(self) -> None:
        """Motor events -> timed commands, under the MotorRules."""
        while not self.done.is_set():
            message = self.motor.get(timeout=0.02)
            actions = None
            if isinstance(message, Motor):  # the inbox takes nothing else
                try:
                    actions = motor_actions(message, self.run_id)
                    if self.too_old(message):
                        continue
                except BusError as e:
                    self.motor.refuse(e, f"(tick {message.tick})")
                    continue
            now = time.monotonic()
            if actions is not None and not self.driven and self.brain.alive:
                self.driven = True
                log.info("a brain drives the robot")
            call = self.rules.decide(now, self.brain.alive, actions)
            if call is not None and self.call(call.call, *call.args):
                self.rules.made(call, now)
                if call.call == "stop":
                    self.stats["safety_stops"] += 1
                    log.info("motors stopped: %s", call.why)
                else:
                    self.stats["commands"] += 1

    def too_old(self, message: Motor) -> bool:
        """Whether `message` answers a reading older than --max-command-age (a brain that stalled
        and now catches up): dropped, counted, logged. BusError for a reading not yet published."""
        polls = self.stats["polls"]
        if message.reading >= polls:
            raise BusError(f"does not fit the run: answers reading {message.reading}, the robot has published {polls}")
        how_old = staleness(self.published, polls, message.reading, time.monotonic(), self.config.max_command_age)
        if how_old is None:
            return False
        self.stats["stale_commands"] += 1
        if self.stats["stale_commands"] <= 5 or self.stats["stale_commands"] % 1000 == 0:
            log.warning(
                "dropped a motor command answering a reading %s (%d dropped so far)",
                how_old,
                self.stats["stale_commands"],
            )
        return True

    def run(self) -> None:
        worker = threading.Thread(target=self.commands, name="motor commands", daemon=True)
        worker.start()
        try:
            self.poll()
        finally:
            self.done.set()
            worker.join(timeout=2)
            self.call("stop")
            self.stats["rejected_messages"] = self.bus.rejections()
            self.stats["seconds"] = round(time.monotonic() - self.started, 3)
            if self.stats["collisions"] and self.stats["collisions"][-1][1] is None:
                self.stats["collisions"][-1][1] = self.stats["seconds"]


def backend_from(config: GatewayConfig):
    if config.backend == "sim":
        return SimBackend(
            seed=config.sim_seed,
            patch_cm=config.sim_patch_cm,
            object_cm=config.sim_object_cm,
            link_ms=config.link_ms,
            map_path=config.sim_map,
        )
    return EV3Backend(protocol=config.protocol, host=config.host, wiring=wiring_of(config))


def run(config: GatewayConfig, session: Session, backend) -> int:
    bus = Bus(session, config.bus.group, "gateway")
    gateway = Gateway(backend, bus, config)
    bus.watch_others(lambda: f" ({gateway.stats['polls']} polls, {time.monotonic() - gateway.started:.1f} s in)")
    control = bus.outbox(keys.control(bus.group))
    # Ctrl-C and SIGTERM end the loops between two robot calls: an exception raised inside ev3-dc
    # would leave its lock taken, and the final stop command would wait for it forever
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: gateway.done.set())
    try:
        gateway.run()
    finally:
        control.put(
            Control(tick=gateway.stats["polls"], command="end", run=gateway.run_id)
        )  # the brain saves, the recorder ends
        backend.close()
        bus.close()
        log.info("gateway done: %s", {k: len(v) if k == "collisions" else v for k, v in gateway.stats.items()})
        if config.stats:
            config.stats.parent.mkdir(parents=True, exist_ok=True)
            config.stats.write_text(json.dumps(gateway.stats))
    return 0


def main(argv=None) -> int:
    made = {}

    def make_backend(config: GatewayConfig) -> None:
        """Before the bus: wiring refused, a map file unread, or the simulated floor built (seconds)."""
        try:
            made["backend"] = backend_from(config)
        except LinkUnavailable as e:  # not a usage error: this machine lacks a piece the options need
            log.error("%s", e)
            raise SystemExit(1) from None
        except (RobotLinkError, ValueError, OSError) as e:
            log.error("%s", e)
            raise SystemExit(2) from None
        except ImportError as e:  # the gateway installed alone (docs/robot.md) has no world
            log.error("--backend %s needs the simulated world, which this install leaves out (%s)", config.backend, e)
            raise SystemExit(2) from None

    return service_main(
        "gateway",
        parser(),
        lambda config, session: run(config, session, made["backend"]),
        argv,
        prepare=make_backend,
        config=GatewayConfig,
    )


if __name__ == "__main__":
    sys.exit(main())
