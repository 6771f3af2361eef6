"""Robot backends: one small interface, a real EV3 (ev3-dc) and a simulated one (pymunk world).

    connect()            open the link (RobotLinkError if it cannot)
    searching() -> str   what a connect() does while the robot is not there, where it takes a while
    read() -> Reading    colour code, ultrasonic distance in cm, touch; one round trip
    forward(ms)          both motors forward for ms milliseconds
    spin(ms, direction)  motors in opposite directions (+1 right, -1 left) for ms milliseconds
    stop()               motors off now
    close()

Any failure of the link surfaces as RobotLinkError, whatever the transport said; what this
machine lacks for a link (missing_for) as LinkUnavailable, when the EV3 backend is made.
"""

from __future__ import annotations

import errno
import math
import platform
import socket
import struct
import threading
import time
import traceback
from dataclasses import dataclass
from typing import cast

import numpy as np

# EV3 colour sensor, mode COL-COLOR: 0 none, 1 black, 2 blue, 3 green, 4 yellow, 5 red, 6 white, 7 brown
NO_COLOUR, BLACK, GREEN, RED, WHITE = 0, 1, 3, 5, 6
EV3_TOUCH, EV3_COLOR, EV3_ULTRASONIC = 16, 29, 30
PORT_BITS = {"A": 1, "B": 2, "C": 4, "D": 8}


LINK_TIMEOUT_S = 0.5  # a brick that does not answer within this is lost (ev3-dc would wait forever on a
# silent WiFi link, and the gateway with it, unable even to stop the motors or to say so)


class RobotLinkError(ConnectionError):
    """The robot cannot be reached or stopped answering."""


class LinkUnavailable(Exception):
    """This machine lacks what the link needs, which no retry can bring: the gateway does not start."""


def missing_for(protocol: str) -> str | None:
    """What this machine lacks for an EV3 link over `protocol`, in words with how to get it; None
    where nothing is missing (the brick itself may still be absent: that is retried)."""
    if protocol == "Bluetooth" and not hasattr(socket, "AF_BLUETOOTH"):
        return (
            "--protocol Bluetooth needs Bluetooth sockets (socket.AF_BLUETOOTH), which this Python was built "
            "without: use a Python built with BlueZ's headers (the Linux distribution's python3 is), or --protocol "
            "USB or WiFi"
        )
    if protocol == "USB" and platform.system() != "Darwin":  # ev3-dc reaches USB through hidapi on macOS
        import usb.core

        try:
            usb.core.find(find_all=True)  # picks a backend; the devices are listed only when iterated
        except usb.core.NoBackendError:
            return (
                "--protocol USB needs libusb, which pyusb does not find on this machine: install it "
                "(Debian, Ubuntu, Raspberry Pi OS: sudo apt install libusb-1.0-0) and start the gateway again"
            )
    return None


@dataclass(frozen=True)
class Reading:
    colour: int  # EV3 colour code
    distance_cm: float  # ultrasonic; 255 = nothing seen
    touch: bool
    at: float  # time.monotonic() of the reading


@dataclass(frozen=True)
class Wiring:
    """Where things are plugged in, and how fast the motors run (EV3 speed -100..100)."""

    touch: int = 1  # sensor ports 1-4
    colour: int = 3
    ultrasonic: int = 4
    motors: str = "BC"  # the two drive motors
    speed: int = 50
    spin_speed: int = 30

    def __post_init__(self):
        motors = self.motors.upper()
        if len(motors) != 2 or len(set(motors)) != 2 or not set(motors) <= set(PORT_BITS):
            raise ValueError(f"--motors must name two different motor ports of A, B, C, D, got {self.motors!r}")
        ports = {"touch": self.touch, "colour": self.colour, "ultrasonic": self.ultrasonic}
        if len(set(ports.values())) != 3 or not all(1 <= p <= 4 for p in ports.values()):
            raise ValueError(f"the three sensors need three different ports of 1-4, got {ports}")
        if not -100 <= self.speed <= 100:
            raise ValueError(f"--speed must be within -100..100, got {self.speed}")
        if not 0 <= self.spin_speed <= 100:
            raise ValueError(f"--spin-speed must be within 0..100, got {self.spin_speed}")

    @property
    def motor_bits(self) -> int:
        return sum(PORT_BITS[p] for p in self.motors.upper())


class Backend:
    def searching(self) -> str:
        """What connect() does while the robot is not there, in words, where it takes a while ("" if not)."""
        return ""

    def connect(self) -> None: ...
    def read(self) -> Reading: ...
    def forward(self, ms: int) -> None: ...
    def spin(self, ms: int, direction: int) -> None: ...
    def stop(self) -> None: ...
    def close(self) -> None: ...


class EV3Backend(Backend):
    """A LEGO EV3 with stock firmware, through the direct-command protocol (ev3-dc).

    protocol: "WiFi" (finds the brick by its UDP beacon), "USB" or "Bluetooth" (host: its MAC).
    All three sensors are read in one direct command; motors get timed synchronised commands.
    """

    def __init__(self, protocol: str = "WiFi", host: str | None = None, wiring: Wiring = Wiring()):
        self.protocol, self.host, self.wiring = protocol, host, wiring
        self._ev3 = None
        self._link, self._lost = None, False  # the link's socket (WiFi, Bluetooth); whether it failed
        try:
            import ev3_dc
        except ImportError:
            raise RobotLinkError("the ev3 backend needs the ev3-dc package: pip install 'spikinglab[ev3]'") from None
        missing = missing_for(protocol)
        if missing:
            raise LinkUnavailable(missing)
        self._dc = ev3_dc
        w, dc = wiring, ev3_dc
        self._read_ops = b"".join(
            dc.opInput_Device
            + dc.READY_SI
            + dc.LCX(0)
            + dc.LCX(port - 1)
            + dc.LCX(kind)
            + dc.LCX(mode)
            + dc.LCX(1)
            + dc.GVX(4 * k)
            for k, (port, kind, mode) in enumerate(
                ((w.colour, EV3_COLOR, 2), (w.ultrasonic, EV3_ULTRASONIC, 0), (w.touch, EV3_TOUCH, 0))
            )
        )

    def searching(self) -> str:
        if self.protocol != "WiFi":
            return ""
        return (
            f"listening for the beacon {'of brick ' + self.host if self.host else 'of an EV3'} on UDP port 3015 "
            "(a brick sends one about every 10 s; ev3-dc gives up a try after 10 s without one)"
        )

    def connect(self) -> None:
        try:
            # ev3-dc annotates host as str but takes None (find the brick by its beacon): cast for its annotation
            self._ev3 = self._dc.EV3(protocol=self.protocol, host=cast(str, self.host))
        except Exception as e:  # ev3-dc raises NoEV3, OSError, usb errors, AssertionError, ...
            self._ev3 = None
            close_sockets_of(e)
            why = str(e)
            if isinstance(e, OSError) and e.errno == errno.EADDRINUSE and self.protocol == "WiFi":
                why = "UDP port 3015, where a brick's beacon comes, is held by another program (another gateway?)"
            raise RobotLinkError(f"cannot connect to the EV3 over {self.protocol}: {why}") from None
        # ev3-dc leaves Nagle on: a motor command (no reply) sent while the previous small packet is
        # unacknowledged would wait for the brick's delayed ACK, about 40 ms
        link = getattr(getattr(self._ev3, "_physical_ev3", None), "_socket", None)
        if isinstance(link, socket.socket):
            link.settimeout(LINK_TIMEOUT_S)
            if link.family in (socket.AF_INET, socket.AF_INET6):
                link.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._link, self._lost = link, False

    def _send(self, ops: bytes, global_mem: int = 0) -> bytes:
        if self._ev3 is None or self._lost:  # a failed call can leave ev3-dc's own lock held: never again
            raise RobotLinkError("not connected" if self._ev3 is None else "EV3 link: lost, not yet linked again")
        try:
            return self._ev3.send_direct_cmd(ops, global_mem=global_mem)
        except Exception as e:  # broken pipe, empty reply (struct.error), DirCmdError, a timeout, ...
            self._lost = True
            raise RobotLinkError(f"EV3 link: {type(e).__name__}: {e or 'no answer'}") from None

    def read(self) -> Reading:
        reply = self._send(self._read_ops, global_mem=12)
        if len(reply) != 12:
            raise RobotLinkError(f"EV3 link: a {len(reply)}-byte reply to a 12-byte read")
        colour, distance, touch = struct.unpack("<3f", reply)
        return Reading(int(round(colour)), float(distance), touch > 0.5, time.monotonic())

    def _time_sync(self, speed: int, turn: int, ms: int) -> None:
        dc = self._dc
        self._send(
            dc.opOutput_Time_Sync
            + dc.LCX(0)
            + dc.LCX(self.wiring.motor_bits)
            + dc.LCX(speed)
            + dc.LCX(turn)
            + dc.LCX(int(ms))
            + dc.LCX(1)
        )

    def forward(self, ms: int) -> None:
        self._time_sync(self.wiring.speed, 0, ms)

    def spin(self, ms: int, direction: int) -> None:
        self._time_sync(self.wiring.spin_speed, 200 if direction > 0 else -200, ms)

    def stop(self) -> None:
        dc = self._dc
        self._send(dc.opOutput_Stop + dc.LCX(0) + dc.LCX(self.wiring.motor_bits) + dc.LCX(1))

    def close(self) -> None:
        if self._ev3 is not None:
            if self._lost and isinstance(self._link, socket.socket):
                # reset, not close: a command still in flight on a lost link must never reach the
                # brick late, when the link comes back (a closed connection would still deliver it)
                self._link.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            try:
                self._ev3.__exit__(None, None, None)  # frees the socket and ev3-dc's device registry
            except Exception:  # a link that is already gone
                pass
            if isinstance(self._link, socket.socket):  # closed here too: ev3-dc closes only what it registered
                self._link.close()
            self._ev3, self._link = None, None


def close_sockets_of(error: BaseException) -> None:
    """Close the sockets a failed connect left open in its frames: ev3-dc raises NoEV3 with its
    beacon socket (UDP port 3015) still bound, so every later try failed with "Address already in
    use" and a brick that came after the first try was never found."""
    for frame, _ in traceback.walk_tb(error.__traceback__):
        for value in frame.f_locals.values():
            if isinstance(value, socket.socket):
                value.close()


def sim_floor(patch_cm: float, object_cm: float, map_path=None) -> tuple:
    """The simulated EV3's floor as World params and grid (None: the paper's); ValueError where its
    objects do not fit their squares, MapError where the map cannot be read."""
    from services.world.world import map_world, params_for

    if not 0 < object_cm <= patch_cm:
        raise ValueError(f"the objects ({object_cm} cm) must fit their squares ({patch_cm} cm)")
    return map_world(map_path, params_for("paper")) if map_path else (params_for("paper"), None)


class SimBackend(Backend):
    """A simulated EV3 on the paper's floor, in real time.

    The floor is the world's map, `patch_cm` a square. As in the paper, an object of the
    ultrasonic sensor's height (`object_cm` wide) stands in the centre of every black and red
    square, so the colour sensor sees black or red for (patch_cm - object_cm) / 2 before the
    ultrasonic reads a collision (below 5 cm). The robot is a point at its sensors: it stalls
    against an object, and a simulated experimenter presses the touch sensor while it is on food
    and carries it back to the start when it leaves the floor.
    """

    def __init__(
        self,
        seed: int = 0,
        patch_cm: float = 30.0,
        object_cm: float = 15.0,
        speed_cm_s: float = 20.0,
        turn_deg_s: float = 50.0,
        link_ms: float = 5.0,
        map_path=None,
    ):
        from services.world.physics import build_objects
        from services.world.world import BLACK as W_BLACK
        from services.world.world import RED as W_RED
        from services.world.world import World

        params, grid = sim_floor(patch_cm, object_cm, map_path)
        self.world = World(params, seed=seed, grid=grid)
        self.objects = build_objects(self.world, object_cm / patch_cm, colours=(W_BLACK, W_RED))
        self.patch_cm, self.speed, self.turn, self.link_s = patch_cm, speed_cm_s / patch_cm, turn_deg_s, link_ms / 1000
        self._motion = ("stop", 0, 0.0)  # kind, direction, until
        self._last = time.monotonic()
        self._lock = threading.Lock()
        self.connected = False

    def connect(self) -> None:
        self.connected = True
        self._last = time.monotonic()

    def _advance(self, now: float) -> None:
        from services.world.physics import ray

        kind, direction, until = self._motion
        dt = max(0.0, min(now, until) - self._last)
        if kind == "forward":
            heading = float(self.world.heading[0])
            step = self.speed * dt
            _, free = ray(self.objects, tuple(self.world.pos[0]), heading, step)
            if free is not None:  # stalls against the object
                step = max(0.0, free - 1e-6)
            h = math.radians(heading)
            self.world.pos[0] += step * np.array([math.sin(h), math.cos(h)])
        elif kind == "spin":
            self.world.heading[0] = (self.world.heading[0] + direction * self.turn * dt) % 360
        p = self.world.params
        x, y = self.world.pos[0]
        if not (p.x_min - 0.5 <= x <= p.x_max + 0.5 and p.y_min - 0.5 <= y <= p.y_max + 0.5):  # off the floor
            self.world.pos[0] = p.start
        self._last = now

    def read(self) -> Reading:
        from services.world.physics import ray
        from services.world.world import BLACK as W_BLACK
        from services.world.world import GREEN as W_GREEN
        from services.world.world import RED as W_RED

        if not self.connected:
            raise RobotLinkError("simulated EV3: not connected")
        time.sleep(self.link_s)  # a USB direct command takes about 6-9 ms; WiFi a few
        with self._lock:
            now = time.monotonic()
            self._advance(now)
            under = self.world.patch_at(0)
            colour = {W_BLACK: BLACK, W_RED: RED, W_GREEN: GREEN}.get(under, WHITE)
            _, d = ray(self.objects, tuple(self.world.pos[0]), float(self.world.heading[0]), 255 / self.patch_cm)
        distance = 255.0 if d is None else round(d * self.patch_cm, 1)
        return Reading(colour, distance, under == W_GREEN, now)

    def _start(self, kind: str, direction: int, ms: int) -> None:
        with self._lock:
            now = time.monotonic()
            self._advance(now)
            self._motion = (kind, direction, now + ms / 1000)

    def forward(self, ms: int) -> None:
        self._start("forward", 0, ms)

    def spin(self, ms: int, direction: int) -> None:
        self._start("spin", 1 if direction > 0 else -1, ms)

    def stop(self) -> None:
        self._start("stop", 0, 0)

    def close(self) -> None:
        self.connected = False
