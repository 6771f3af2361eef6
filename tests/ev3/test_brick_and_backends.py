"""The fake brick speaks the EV3 protocol; the ev3 backend (ev3-dc, unchanged) drives it; the
simulated EV3 senses its world; readings map onto the insect's senses."""

import math
import socket
import struct
import time

import pytest
from ev3_dc import GVX, LCX

from services.ev3_gateway.backends import EV3Backend, Reading, RobotLinkError, SimBackend, Wiring
from services.ev3_gateway.fake_brick import BEACON_PORT, FakeBrick, parameter
from services.ev3_gateway.service import sensor_values
from services.vocabulary import INSECT_SENSORS


@pytest.mark.parametrize("value", [0, 5, 31, -1, -32, 100, -127, 1000, -20000, 70000, -70000])
def test_constant_encodings_decode(value):
    encoded = LCX(value)
    assert parameter(encoded, 0) == (value, "const", len(encoded))


@pytest.mark.parametrize("address", [0, 4, 31, 32, 100, 1000])  # (ev3-dc's GVX cannot encode 128..255)
def test_global_variable_encodings_decode(address):
    encoded = GVX(address)
    assert parameter(encoded, 0) == (address, "global", len(encoded))


def frame(ops: bytes, counter=7, reply=True, global_mem=0) -> bytes:
    return (
        struct.pack("<HH", len(ops) + 5, counter)
        + bytes([0x00 if reply else 0x80])
        + struct.pack("<H", global_mem)
        + ops
    )


def reply_to(brick: FakeBrick, request: bytes) -> bytes:
    """The brick's reply to a request that asks for one."""
    answer = brick.execute(request)
    assert answer is not None, "no reply"
    return answer


def test_fake_brick_answers_reads_and_refuses_what_a_brick_would():
    brick = FakeBrick(colour=5, distance_cm=3.5, touch=1)
    read = bytes([0x99, 0x1D]) + LCX(0) + LCX(2) + LCX(29) + LCX(2) + LCX(1) + GVX(0)
    reply = reply_to(brick, frame(read, global_mem=4))
    assert reply[:5] == struct.pack("<HH", 7, 7) + b"\x02" and struct.unpack("<f", reply[5:]) == (5.0,)
    assert (
        brick.execute(frame(bytes([0xB1]) + LCX(0) + LCX(6) + LCX(50) + LCX(0) + LCX(500) + LCX(1), reply=False))
        is None
    )
    assert (brick.commands[-1].kind, brick.commands[-1].ms, brick.commands[-1].ports) == ("time_sync", 500, 6)
    wrong_type = bytes([0x99, 0x1D]) + LCX(0) + LCX(2) + LCX(30) + LCX(0) + LCX(1) + GVX(0)
    assert reply_to(brick, frame(wrong_type, global_mem=4))[4] == 0x04  # the colour sensor is on port 3
    assert reply_to(brick, frame(bytes([0x84, 0x00]), global_mem=0))[4] == 0x04  # an opcode it does not have
    assert "no sensor of type 30 on port 3" in brick.errors[0]


def test_ev3_backend_drives_the_fake_brick_over_its_wifi_protocol():
    """Also once a try heard no beacon (ev3-dc's 10 s): ev3-dc's error holds its socket bound to UDP
    port 3015 (in the gateway, until the garbage collector came), and every later try failed."""
    robot = EV3Backend("WiFi", wiring=Wiring(motors="BC", speed=40, spin_speed=25))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("", BEACON_PORT))
        with pytest.raises(RobotLinkError, match="UDP port 3015, where a brick's beacon comes, is held by another"):
            robot.connect()
    with pytest.raises(RobotLinkError, match="No EV3 device found") as failed:
        robot.connect()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as beacon:
        beacon.bind(("", BEACON_PORT))  # free, though the error is still held
    del failed
    with FakeBrick() as brick:
        robot.connect()  # found by its UDP beacon, TCP unlock, as with a real brick
        brick.set(colour=5, distance_cm=4.2, touch=1)
        reading = robot.read()
        assert (reading.colour, reading.distance_cm, reading.touch) == (5, pytest.approx(4.2), True)
        reads = brick.reads
        robot.read()
        assert brick.reads == reads + 3  # all three sensors in one direct command
        robot.forward(500)
        robot.spin(100, -1)
        robot.stop()
        robot.read()  # a reply: the commands before it have all been executed
        forward, spin, stop = brick.commands
        assert (forward.kind, forward.ports, forward.speed, forward.turn, forward.ms) == ("time_sync", 6, 40, 0, 500)
        assert (spin.speed, spin.turn, spin.ms) == (25, -200, 100)
        assert (stop.kind, stop.ports, stop.brake) == ("stop", 6, 1)
        assert spin.at - forward.at < 0.01  # no Nagle delay between commands
        brick.disconnect()
        with pytest.raises(RobotLinkError, match="EV3 link"):
            for _ in range(3):
                robot.read()
        robot.close()
        robot.connect()
        assert robot.read().colour == 5 and brick.connections == 2
        robot.close()


def test_no_brick_is_a_clear_error(monkeypatch):
    import ev3_dc.ev3 as dc

    class NoBeacon:
        def __init__(self, *a, **k):
            raise dc.NoEV3("No EV3 device found")

    monkeypatch.setattr(dc, "_PhysicalEV3", NoBeacon)  # spare the test ev3-dc's 10 s wait for a beacon
    with pytest.raises(RobotLinkError, match="cannot connect to the EV3 over WiFi: No EV3 device found"):
        EV3Backend("WiFi").connect()


def test_readings_map_onto_the_insects_senses():
    def sensed(**kw):
        row = sensor_values(Reading(**{"colour": 6, "distance_cm": 100.0, "touch": False, "at": 0.0, **kw}), 5.0, 0.0)[
            0
        ]
        return {name: row[k] for k, name in enumerate(INSECT_SENSORS) if not math.isnan(row[k])}

    assert sensed() == {}
    assert sensed(colour=1) == {"smell_black": 0.0}
    assert sensed(colour=5) == {"smell_red": 0.0}
    assert sensed(colour=3) == {"smell_green": 0.0}
    assert sensed(colour=2) == {} and sensed(colour=0) == {}  # blue, none: floor
    assert sensed(distance_cm=4.9) == {"pain": 0.0} and sensed(distance_cm=5.0) == {}
    assert sensed(touch=True, colour=3) == {"smell_green": 0.0, "reward": 0.0}


ARENA = """\
##########
#........#
#S.....G.#
#........#
##########
"""


def test_simulated_ev3_senses_and_moves_in_its_world(tmp_path):
    (tmp_path / "arena.txt").write_text(ARENA)
    # 30 cm squares, 15 cm objects in the centre of the black ones; 20 patches/s, 900 deg/s
    robot = SimBackend(link_ms=0, speed_cm_s=600.0, turn_deg_s=900.0, map_path=tmp_path / "arena.txt")
    robot.connect()
    robot.world.heading[0] = 270.0  # west, towards the wall at x = 0; the robot starts at (1, 2)
    reading = robot.read()
    assert reading.distance_cm == pytest.approx(22.5)  # to the object's face at x = 0.25: 0.75 of a 30 cm square
    assert (reading.colour, reading.touch) == (6, False)  # white floor
    robot.world.heading[0] = 90.0  # east, towards the food at x = 7 and the wall's object at x = 8.75
    assert robot.read().distance_cm == pytest.approx(232.5)  # food is not an obstacle
    robot.forward(100)  # 20 patches/s for 0.1 s: 2 patches
    time.sleep(0.15)
    robot.read()
    assert robot.world.pos[0] == pytest.approx([3.0, 2.0], abs=0.05)
    robot.spin(100, 1)  # 900 deg/s for 0.1 s: 90 degrees to the right
    time.sleep(0.15)
    robot.read()
    assert robot.world.heading[0] == pytest.approx(180.0, abs=1.0)
    robot.world.pos[0] = (7.0, 2.0)  # on the food: the experimenter presses the touch sensor
    reading = robot.read()
    assert reading.touch and reading.colour == 3
    # west into the wall: onto its black square, where the colour sensor sees black before the
    # ultrasonic sees the object close; then stalled against the object, not through it
    robot.world.pos[0], robot.world.heading[0] = (1.0, 2.0), 270.0
    robot.forward(30)  # 0.6 patches: on the black square, 4.5 cm from the object
    time.sleep(0.05)
    reading = robot.read()
    assert reading.colour == 1 and reading.distance_cm == pytest.approx(4.5, abs=1.0)
    robot.forward(300)  # 6 patches, were it free
    time.sleep(0.35)
    reading = robot.read()
    assert robot.world.pos[0][0] == pytest.approx(0.25, abs=0.02) and reading.distance_cm < 1
