"""A fake LEGO EV3 brick on loopback that speaks the real WiFi direct-command protocol.

What a brick with stock firmware does on WiFi, as far as a client such as ev3-dc sees it:
  1. it broadcasts a UDP beacon to port 3015 ("Serial-Number: ...\\r\\nPort: 5555\\r\\nName: ...
     \\r\\nProtocol: EV3\\r\\n"); here the beacon goes to 127.0.0.1:3015 while no client is connected;
  2. the client opens TCP to that port and sends an unlock request ("GET /target?sn=...VMTP1.0
     \\nProtocol: EV3"); the brick answers "Accept:EV340\\r\\n\\r\\n";
  3. then direct commands: [length u16][counter u16][type u8: 0x00 reply, 0x80 no reply]
     [memory u16: global bytes in the low 10 bits, local in the top 6][operations], answered (if
     asked) by [length u16][counter u16][0x02 ok | 0x04 error][global memory].

Operations understood: opInput_Device (0x99) READY_SI (0x1D) and READY_RAW (0x1C), which read
the scripted sensors; opOutput_Time_Sync (0xB1) and opOutput_Stop (0xA3), which are logged with
their time. Anything else is answered with an error, as is a read of a port whose sensor type does
not match. Parameters use the EV3's encodings (LC0/LC1/LC2/LC4 constants, LV/GV variables).
Only one fake brick per machine at a time: the beacon port 3015 is fixed.

When its link drops, a real brick goes on with what it was told: its motors run the last command
to its end (a timed one ends by itself; opOutput_Time_Sync with 0 ms runs until stopped) and
nothing else stops them. `disconnect()` is a link that closes (the client sees it at once);
`drop_link(s)` is a radio that goes silent for s seconds (WiFi out of range): nothing is answered
and, as over TCP, what the client sends meanwhile waits in flight; when the link comes back it is
delivered late and executed, unless the client has reset the connection (a reset discards it),
and a client that went away is replaced by a new one. `moving_at(t)` says whether the motors turn.
"""

from __future__ import annotations

import argparse
import logging
import socket
import struct
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field

from services.options import Parser, number_within, positive
from services.runtime import process_main

log = logging.getLogger("spikinglab.fake_brick")

BEACON_PORT = 3015
KEPT_COMMANDS = 100_000  # motor commands kept for inspection (minutes of a brain at full speed)
OP_INPUT_DEVICE, OP_OUTPUT_TIME_SYNC, OP_OUTPUT_STOP = 0x99, 0xB1, 0xA3
READY_RAW, READY_SI = 0x1C, 0x1D
REPLY_OK, REPLY_ERROR = 0x02, 0x04
EV3_TOUCH, EV3_COLOR, EV3_ULTRASONIC = 16, 29, 30


class ProtocolError(ValueError):
    """A direct command the fake brick cannot execute (the real one would answer an error)."""


def parameter(ops: bytes, i: int) -> tuple[int, str, int]:
    """Decode one parameter at ops[i]: (value or address, "const" | "local" | "global", next i)."""
    b = ops[i]
    if not b & 0x80:  # short format: 6-bit constant, or 5-bit variable address
        if not b & 0x40:
            value = b & 0x3F
            return (value - 64 if value & 0x20 else value), "const", i + 1
        return b & 0x1F, ("global" if b & 0x20 else "local"), i + 1
    size = b & 0x07
    if size == 4:  # a zero-terminated string constant
        end = ops.index(0, i + 1)
        return 0, "const", end + 1
    n, fmt = {1: (1, "b"), 2: (2, "h"), 3: (4, "i")}[size]
    if b & 0x40:  # a variable: unsigned address
        value = int.from_bytes(ops[i + 1 : i + 1 + n], "little")
        return value, ("global" if b & 0x20 else "local"), i + 1 + n
    return struct.unpack("<" + fmt, ops[i + 1 : i + 1 + n])[0], "const", i + 1 + n


@dataclass
class MotorCommand:
    at: float  # time.monotonic() when the brick executed it
    kind: str  # "time_sync" or "stop"
    ports: int  # bit field A=1 B=2 C=4 D=8
    speed: int = 0
    turn: int = 0
    ms: int = 0
    brake: int = 0
    link: int = 0  # the connection (1, 2, ...) that brought it


@dataclass
class FakeBrick:
    """Start with `start()`; set `colour`, `distance_cm`, `touch`; read `commands`; `disconnect()` drops the client."""

    serial: str = "0016533F8491"
    name: str = "FakeEV3"
    port: int = 0  # TCP port; 0: a free one with 4 digits (the beacon format wants 4)
    sensor_ports: dict = field(default_factory=lambda: {0: EV3_TOUCH, 2: EV3_COLOR, 3: EV3_ULTRASONIC})
    colour: int = 6  # white floor
    distance_cm: float = 100.0
    touch: int = 0

    def __post_init__(self):
        self.commands: deque[MotorCommand] = deque(maxlen=KEPT_COMMANDS)  # the latest: bounded for a long soak
        self.commanded = 0  # motor commands executed, all told
        self.reads = 0
        self.errors: list[str] = []
        self.connections = 0
        self.changed_at = time.monotonic()  # when a sensor value last changed (benchmark)
        self._stop = threading.Event()
        self._client: socket.socket | None = None
        self._lock = threading.Lock()
        self._silent_until = 0.0  # drop_link(): no radio until then (time.monotonic())

    def set(self, **values) -> None:
        """Change sensor values (colour, distance_cm, touch) at once, and note when."""
        with self._lock:
            for key, value in values.items():
                setattr(self, key, value)
            self.changed_at = time.monotonic()

    # --- life cycle ----------------------------------------------------------------------------
    def start(self) -> FakeBrick:
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if self.port:
            self._server.bind(("127.0.0.1", self.port))
        else:
            for candidate in range(5555, 9999):
                try:
                    self._server.bind(("127.0.0.1", candidate))
                    break
                except OSError:
                    continue
        self.port = self._server.getsockname()[1]
        self._server.listen(1)
        self._server.settimeout(0.2)
        self._threads = [
            threading.Thread(target=self._beacon, daemon=True),
            threading.Thread(target=self._serve, daemon=True),
        ]
        for t in self._threads:
            t.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self.disconnect()
        for t in self._threads:
            t.join(timeout=2)
        self._server.close()

    def disconnect(self) -> None:
        """Drop the client, as a brick that lost its link would; it beacons again for a new one."""
        client, self._client = self._client, None
        if client is not None:
            try:
                client.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            client.close()

    def drop_link(self, seconds: float) -> None:
        """The radio goes silent for `seconds`: nothing answered, nothing beaconed; the motors go on."""
        self._silent_until = time.monotonic() + seconds

    @property
    def silent(self) -> bool:
        return time.monotonic() < self._silent_until

    def moving_at(self, t: float) -> bool:
        """Whether the motors turn at time.monotonic() `t`, as the commands executed before it left them."""
        last = next((c for c in reversed(self.commands) if c.at <= t), None)
        return last is not None and last.kind == "time_sync" and (last.ms == 0 or t < last.at + last.ms / 1000)

    @property
    def connected(self) -> bool:
        return self._client is not None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # --- network -------------------------------------------------------------------------------
    def _beacon(self) -> None:
        udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        text = (f"Serial-Number: {self.serial}\r\nPort: {self.port}\r\nName: {self.name}\r\nProtocol: EV3\r\n").encode()
        while not self._stop.wait(0.1):
            if self._client is None and not self.silent:
                udp.sendto(text, ("127.0.0.1", BEACON_PORT))
        udp.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._server.accept()
            except (TimeoutError, OSError):
                continue
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            try:
                unlock = client.recv(1024)
                if not unlock.startswith(b"GET /target?sn="):
                    client.close()
                    continue
                client.sendall(b"Accept:EV340\r\n\r\n")
            except OSError:
                continue
            self.connections += 1
            self._client = client
            self._handle(client)
            if self._client is client:
                self._client = None

    def _handle(self, client: socket.socket) -> None:
        client.settimeout(0.01)
        buffer, closed = b"", False
        while not self._stop.is_set():
            if not closed:
                try:
                    data = client.recv(65536)
                    closed = not data
                    buffer += data
                except TimeoutError:
                    pass
                except OSError:  # a reset: what was in flight is lost with the connection
                    return
            if self.silent:  # in flight until the radio is back
                continue
            buffer = self._execute_frames(buffer, client)
            if buffer is None or closed:  # a closed connection's last frames were still delivered
                return

    def _execute_frames(self, buffer: bytes, client: socket.socket) -> bytes | None:
        """Execute the whole frames in `buffer`; the rest (None: the client cannot be answered)."""
        while len(buffer) >= 2:
            size = struct.unpack("<H", buffer[:2])[0] + 2
            if len(buffer) < size:
                break
            frame, buffer = buffer[:size], buffer[size:]
            reply = self.execute(frame)
            if reply is not None:
                try:
                    client.sendall(reply)
                except OSError:
                    return None
        return buffer

    # --- direct commands -------------------------------------------------------------------------
    def execute(self, frame: bytes) -> bytes | None:
        """Run one direct command frame; the reply frame, or None if none was asked for."""
        counter, kind = frame[2:4], frame[4]
        memory = struct.unpack("<H", frame[5:7])[0]
        global_mem = bytearray(memory & 0x3FF)
        status = REPLY_OK
        try:
            if kind not in (0x00, 0x80):
                raise ProtocolError(f"command type 0x{kind:02X} is not a direct command")
            self._operations(frame[7:], global_mem)
        except (ProtocolError, IndexError, struct.error, KeyError) as e:
            status = REPLY_ERROR
            self.errors.append(str(e) or type(e).__name__)
            log.warning("fake brick: error in direct command: %s", e)
        if kind != 0x00:
            return None
        return struct.pack("<H", len(global_mem) + 3) + counter + bytes([status]) + bytes(global_mem)

    def _operations(self, ops: bytes, global_mem: bytearray) -> None:
        i = 0
        while i < len(ops):
            op, i = ops[i], i + 1
            if op == OP_INPUT_DEVICE:
                i = self._input_device(ops, i, global_mem)
            elif op == OP_OUTPUT_TIME_SYNC:
                args, i = self._params(ops, i, 6)
                layer, ports, speed, turn, ms, brake = args
                self._executed(
                    MotorCommand(time.monotonic(), "time_sync", ports, speed, turn, ms, brake, self.connections)
                )
            elif op == OP_OUTPUT_STOP:
                args, i = self._params(ops, i, 3)
                self._executed(MotorCommand(time.monotonic(), "stop", args[1], brake=args[2], link=self.connections))
            else:
                raise ProtocolError(f"opcode 0x{op:02X} is not supported by this brick")

    def _executed(self, command: MotorCommand) -> None:
        self.commands.append(command)
        self.commanded += 1

    def _params(self, ops: bytes, i: int, count: int) -> tuple[list[int], int]:
        values = []
        for _ in range(count):
            value, kind, i = parameter(ops, i)
            if kind != "const":
                raise ProtocolError("expected a constant parameter")
            values.append(value)
        return values, i

    def _input_device(self, ops: bytes, i: int, global_mem: bytearray) -> int:
        sub, kind, i = parameter(ops, i)
        if sub not in (READY_SI, READY_RAW):
            raise ProtocolError(f"opInput_Device subcode 0x{sub:02X} is not supported")
        (layer, port, sensor_type, mode, count), i = self._params(ops, i, 5)
        present = self.sensor_ports.get(port)
        if present is None or sensor_type not in (0, present):
            raise ProtocolError(f"no sensor of type {sensor_type} on port {port + 1} (there: {present})")
        with self._lock:
            value = {EV3_COLOR: self.colour, EV3_ULTRASONIC: self.distance_cm, EV3_TOUCH: self.touch}[present]
        self.reads += 1
        for _ in range(count):
            address, where, i = parameter(ops, i)
            if where != "global":
                raise ProtocolError("sensor values go to global memory here")
            data = struct.pack("<f", float(value)) if sub == READY_SI else struct.pack("<i", int(value))
            global_mem[address : address + 4] = data
        return i


def parser() -> Parser:
    p = Parser(
        prog="spikinglab fake-brick",
        description="A fake EV3 brick on loopback for the gateway (--backend ev3) to find and drive: TCP "
        f"127.0.0.1:5555 (the next free port up if taken), found by its beacon to UDP port {BEACON_PORT}. One at "
        "a time on a machine: a gateway links to the first beacon it hears.",
    )
    p.add_argument(
        "--colour",
        type=int,
        choices=range(8),
        default=6,
        help="the colour sensor's reading, an EV3 colour 0-7 (default 6: white; 1 black, 3 green, 5 red)",
    )
    p.add_argument(
        "--distance-cm",
        type=number_within(0, 255, " (what the EV3 ultrasonic sensor reads; 255: nothing seen)"),
        default=100.0,
        help="the ultrasonic sensor's reading, 0 .. 255 (default 100)",
    )
    p.add_argument("--report-every", type=positive, default=10.0, help="seconds between status lines (default 10)")
    return p


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C or SIGTERM, with a status line every --report-every seconds."""
    brick = FakeBrick(colour=args.colour, distance_cm=args.distance_cm).start()
    print(f"fake EV3 on 127.0.0.1:{brick.port}, beaconing to UDP {BEACON_PORT}; Ctrl-C to stop", flush=True)
    try:
        while True:
            time.sleep(args.report_every)
            print(f"reads {brick.reads}, motor commands {brick.commanded}, connected {brick.connected}", flush=True)
    finally:
        brick.stop()


def main(argv=None) -> int:  # to try the gateway by hand, or in a launch file (service = "fake-brick")
    return process_main("fake-brick", parser(), run, argv, interrupted=0)


if __name__ == "__main__":
    sys.exit(main())
