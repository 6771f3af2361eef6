"""Brain (free-running), gateway (ev3 backend -> the fake brick) and recorder as real processes."""

import json
import random
import signal
import time

import numpy as np

from services.brain.checkpoint import save_weights
from services.brain.circuit import load_circuit
from services.brain.engine import Engine
from services.bus import keys
from services.bus.schemas import Array, Motor, encode
from services.ev3_gateway.fake_brick import BEACON_PORT, FakeBrick
from services.ev3_gateway.service import staleness
from services.vocabulary import INSECT_ACTIONS

from ..processes import Watcher, connecting, endpoint, finish, gateway_and_brain, start, wait_for, wait_for_driving
from ..recordings import read
from ..sockets import listeners


def test_robot_chain_senses_moves_survives_a_lost_link_and_stops_without_a_brain(tmp_path):
    gateway_ep, brain_ep = endpoint(tmp_path, "gateway"), endpoint(tmp_path, "brain")
    with FakeBrick() as brick:
        recorder = start(
            "record", *connecting(gateway_ep, brain_ep), "--out", tmp_path / "robot.rrd", log=tmp_path / "recorder.log"
        )
        gateway, brain = gateway_and_brain(
            tmp_path, ["--stats", tmp_path / "gateway.json"], ["--publish-state", "--stats", tmp_path / "brain.json"]
        )
        processes = [recorder, gateway, brain]
        try:
            # the pacemaker keeps the insect walking: MOVE spikes -> forward 500 ms on both drive motors
            wait_for_driving(tmp_path)
            wait_for(lambda: any(c.kind == "time_sync" and c.turn == 0 for c in brick.commands), 60, "a forward")
            forward = next(c for c in brick.commands if c.kind == "time_sync" and c.turn == 0)
            assert (forward.ports, forward.ms, forward.speed) == (0b0110, 500, 50)
            assert not any(c.turn for c in brick.commands)  # nothing hurts: no spin yet

            brick.set(colour=5)  # red under the colour sensor
            time.sleep(1.0)
            brick.set(colour=6, distance_cm=3.0)  # an obstacle 3 cm ahead: pain -> ROTATE -> spin
            wait_for(lambda: any(c.turn == 200 for c in brick.commands), 10, "a spin")
            brick.set(distance_cm=100.0)

            reads = brick.reads
            brick.disconnect()  # the link breaks: reported, and the gateway connects again
            log = tmp_path / "gateway.log"
            wait_for(
                lambda: "robot link lost" in log.read_text() and "robot linked again" in log.read_text(),
                30,
                "the gateway to reconnect",
            )
            wait_for(lambda: brick.reads > reads + 100, 10, "polls on the new link")
            assert brick.connections == 2 and brain.poll() is None  # the brain kept running

            brain.send_signal(signal.SIGKILL)  # the brain dies: the gateway stops the motors
            killed_at = time.monotonic()
            wait_for(lambda: any(c.kind == "stop" and c.at > killed_at for c in brick.commands), 5, "a stop")
            stop = next(c for c in brick.commands if c.kind == "stop" and c.at > killed_at)
            assert stop.at - killed_at < 0.25
            assert "motors stopped: the brain's liveliness token is gone" in log.read_text()

            gateway.send_signal(signal.SIGTERM)
            recorder.send_signal(signal.SIGTERM)
            assert finish(gateway, 30, log) == 0
            assert finish(recorder, 60, tmp_path / "recorder.log") == 0
        finally:
            for p in processes:
                p.kill()
    stats = json.loads((tmp_path / "gateway.json").read_text())
    assert stats["link_losses"] == 1 and stats["commands"] > 0 and stats["polls"] > 1000
    data = read(tmp_path / "robot.rrd")
    spikes = {
        name: len(data.get(f"/brain/agent0/spikes/{k:02d}_{name}", {}).get("tick", []))
        for k, name in enumerate(("BLACK", "RED", "GREEN"))
    }
    assert spikes["RED"] > 50 and spikes["BLACK"] == spikes["GREEN"] == 0  # red reached the RED afferent


def test_a_stalled_brain_stops_the_robot_and_sends_no_backlog_when_it_resumes(tmp_path):
    with FakeBrick() as brick:
        gateway, brain = gateway_and_brain(tmp_path, ["--stats", tmp_path / "gateway.json"])
        try:
            wait_for_driving(tmp_path)
            wait_for(lambda: sum(c.kind == "time_sync" for c in brick.commands) > 10, 60, "the insect walking")
            time.sleep(1.0)
            before = len(brick.commands)
            time.sleep(1.0)
            per_second = len(brick.commands) - before  # forwards of an insect walking freely
            wait_for(
                lambda: brick.commands[-1].kind == "time_sync" and time.monotonic() - brick.commands[-1].at < 0.1,
                10,
                "a command under way",
            )
            brain.send_signal(signal.SIGSTOP)  # frozen: its token stays on the bus, it says nothing
            stalled_at = time.monotonic()
            wait_for(lambda: any(c.kind == "stop" and c.at > stalled_at for c in brick.commands), 5, "a stop")
            stop = next(c for c in brick.commands if c.kind == "stop" and c.at > stalled_at)
            print(f"stall -> motors stopped: {(stop.at - stalled_at) * 1000:.0f} ms")
            assert stop.at - stalled_at < 0.25
            time.sleep(1.5)
            resumed = len(brick.commands)
            brain.send_signal(signal.SIGCONT)
            time.sleep(1.0)
            after = len(brick.commands) - resumed
            assert after < 2 * per_second + 5, (after, per_second)  # once, 312 old commands came in 1.3 s
            assert "the clock stalled for" in (tmp_path / "brain.log").read_text()
            gateway.send_signal(signal.SIGTERM)
            assert finish(gateway, 30, tmp_path / "gateway.log") == 0
        finally:
            brain.send_signal(signal.SIGCONT)
            brain.kill()
            gateway.kill()
    assert "no word from the brain for 200 ms" in (tmp_path / "gateway.log").read_text()


def test_a_link_gone_silent_is_noticed_the_robot_stops_by_itself_and_nothing_arrives_late(tmp_path):
    """WiFi out of range for 2 s (the brick answers nothing, its motors go on with what they were
    told): the gateway says the link is lost within a second (before, it waited on the brick for
    as long as the silence lasted, unable to stop the motors or to say so), the robot stops by
    itself at the end of its last timed command, and nothing sent into the dead link is executed
    late when the radio comes back (the gateway resets it); then the gateway links again."""
    with FakeBrick() as brick:
        gateway, brain = gateway_and_brain(tmp_path, ["--stats", tmp_path / "gateway.json"])
        log = tmp_path / "gateway.log"
        try:
            wait_for_driving(tmp_path)
            wait_for(lambda: sum(c.kind == "time_sync" for c in brick.commands) > 10, 60, "the insect walking")
            dropped_at = time.monotonic()
            brick.drop_link(2.0)
            wait_for(lambda: "robot link lost" in log.read_text(), 5, "the gateway to notice")
            noticed_s = time.monotonic() - dropped_at
            last = [c for c in brick.commands if c.at <= dropped_at][-1]
            still_at = last.at + last.ms / 1000 if last.kind == "time_sync" else last.at
            assert last.ms > 0 and not brick.moving_at(still_at + 0.001)  # timed: it ends by itself
            wait_for(lambda: "robot linked again" in log.read_text(), 10, "the link back")
            polls = brick.reads
            wait_for(lambda: brick.reads > polls + 100, 10, "polls on the new link")
            print(
                f"link silent -> gateway says so in {noticed_s * 1000:.0f} ms; the motors stood still "
                f"{(still_at - dropped_at) * 1000:.0f} ms after the drop"
            )
            assert noticed_s < 1.5 and brick.connections == 2
            late = [c for c in brick.commands if c.link == 1 and c.at > dropped_at]
            assert not late, late  # what was in flight on the lost link never reached the motors
            # the insect walks on over the new link, once the brain has answered a fresh reading
            # (100 polls take a few ms; the commands answering readings from before the loss are stale)
            wait_for(lambda: any(c.link == 2 for c in brick.commands), 10, "a command over the new link")
            gateway.send_signal(signal.SIGTERM)
            assert finish(gateway, 30, log) == 0
        finally:
            brain.kill()
            gateway.kill()
    assert json.loads((tmp_path / "gateway.json").read_text())["link_losses"] == 1


def test_commands_answering_old_or_unpublished_readings_are_dropped(tmp_path):
    gateway_ep = endpoint(tmp_path, "gateway")
    with FakeBrick() as brick:
        # At most 1,000 polls/s: unbounded, the fake brick answers ~20,000/s and this test's Python
        # subscriber fell up to 0.6 s behind, so its "latest" reading was itself too old to answer.
        gateway = start(
            "gateway",
            "--listen",
            gateway_ep,
            "--max-polls",
            1000,
            "--stats",
            tmp_path / "gateway.json",
            log=tmp_path / "gateway.log",
        )
        brain = Watcher([gateway_ep], [keys.sensors(keys.DEFAULT_GROUP)])  # a brain: its token, its motor key
        token = brain.session.liveliness().declare_token(keys.alive(keys.DEFAULT_GROUP, "brain"))
        motor = brain.session.declare_publisher(keys.motor(keys.DEFAULT_GROUP))
        readings = brain.messages[keys.sensors(keys.DEFAULT_GROUP)]
        try:
            wait_for(lambda: len(readings) > 200, 60, "readings")
            time.sleep(0.3)  # reading 0 is now 300 ms old
            latest = readings[-1]

            def rotate(reading: int) -> bytes:
                return encode(
                    Motor(
                        tick=1,
                        names=INSECT_ACTIONS,
                        actions=Array.of(np.array([[1, 0]], np.uint8)),
                        run=latest.run,
                        reading=reading,
                    )
                )

            motor.put(rotate(0))
            motor.put(rotate(latest.tick + 10**9))  # a reading not published yet
            time.sleep(0.3)
            assert not brick.commands
            motor.put(rotate(readings[-1].tick))  # the control: a fresh one is followed
            wait_for(lambda: any(c.turn for c in brick.commands), 5, "the spin")
            gateway.send_signal(signal.SIGTERM)
            assert finish(gateway, 30, tmp_path / "gateway.log") == 0
        finally:
            token.undeclare()
            brain.close()
            gateway.kill()
    stats = json.loads((tmp_path / "gateway.json").read_text())
    assert stats["stale_commands"] == 1
    assert stats["rejected_messages"][keys.motor(keys.DEFAULT_GROUP)] == {"does not fit the run": 1}
    assert "dropped a motor command answering a reading" in (tmp_path / "gateway.log").read_text()


def test_a_reading_is_stale_by_its_publication_time_or_by_count_once_its_time_is_not_kept():
    published = np.zeros(4)
    published[[1, 2, 3, 0]] = [10.0, 10.1, 10.2, 10.3]  # readings 5..8 of 9, at 5 % 4 = 1 onwards
    assert staleness(published, 9, 8, now=10.4, max_age=0.2) is None
    assert staleness(published, 9, 5, now=10.4, max_age=0.2) == "400 ms old"
    assert staleness(published, 9, 4, now=10.4, max_age=0.2) == "5 readings back"  # not the clock's age
    assert staleness(published, 9, -1, now=10.4, max_age=0.2) is None  # answers no reading


def test_the_brain_drives_a_simulated_ev3(tmp_path):
    """The free-running brain says its --load and --save as the lock-step one does."""
    log, loaded, saved = tmp_path / "gateway.log", tmp_path / "start.npz", tmp_path / "end.npz"
    circuit = load_circuit("insect")
    save_weights(loaded, Engine(circuit), circuit)
    gateway, brain = gateway_and_brain(
        tmp_path, ["--backend", "sim", "--stats", tmp_path / "gateway.json"], ["--load", loaded, "--save", saved]
    )
    try:
        wait_for_driving(tmp_path)
        time.sleep(2.0)
        gateway.send_signal(signal.SIGTERM)
        assert finish(gateway, 30, log) == 0
        assert finish(brain, 30, tmp_path / "brain.log") == 0  # the gateway's end ends the brain's run
    finally:
        brain.kill()
        gateway.kill()
    stats = json.loads((tmp_path / "gateway.json").read_text())
    assert stats["polls"] > 100 and stats["commands"] > 3 and stats["link_losses"] == 0
    said = log.read_text()
    assert said.count("brain is on the bus") == 1 and "the brain is on the bus (" in said  # one line, with the polls
    said = (tmp_path / "brain.log").read_text()
    assert f"weights loaded from {loaded} (1 agent)" in said and f"weights saved to {saved}" in said


def test_duration_counts_from_the_first_reading_not_from_the_start(tmp_path):
    """A gateway run for 1 s waits 2 s for its brick (listening for the brick's WiFi beacon), then
    links, publishes its first reading, and only then runs its 1 s."""
    log = tmp_path / "gateway.log"
    serial = f"{random.getrandbits(48):012X}"  # this brick's, not another test's on this machine
    host = ":".join(serial[i : i + 2] for i in range(0, 12, 2))
    gateway = start(
        "gateway",
        *(
            "--host",
            host,
            "--listen",
            endpoint(tmp_path, "gateway"),
            "--duration",
            1,
            "--stats",
            tmp_path / "gateway.json",
        ),
        log=log,
    )
    try:
        beacon = f":{BEACON_PORT}"
        wait_for(lambda: any(s.address.endswith(beacon) for s in listeners(gateway.pid)), 60, "the gateway to listen")
        time.sleep(2.0)
        with FakeBrick(serial=serial) as brick:
            wait_for(lambda: "robot linked" in log.read_text(), 30, "the link")
            linked_at = time.monotonic()
            assert finish(gateway, 30, log) == 0
            ran_s = time.monotonic() - linked_at
    finally:
        gateway.kill()
    stats = json.loads((tmp_path / "gateway.json").read_text())
    assert stats["polls"] > 100 and brick.reads >= 3 * stats["polls"], stats  # 3 sensors a poll
    assert ran_s > 0.8, ran_s


def test_sigterm_ends_a_gateway_that_listens_for_its_brick(tmp_path):
    """No brick: each try listens for its WiFi beacon, 10 s in ev3-dc, deaf to signals meanwhile.
    SIGTERM (Ctrl-C alike) ends the gateway within that try, and the gateway said what it waits for."""
    log = tmp_path / "gateway.log"
    serial = f"{random.getrandbits(48):012X}"  # no brick of another test on this machine is this one
    host = ":".join(serial[i : i + 2] for i in range(0, 12, 2))
    gateway = start("gateway", "--host", host, "--listen", endpoint(tmp_path, "gateway"), log=log)
    try:
        beacon = f":{BEACON_PORT}"
        wait_for(lambda: any(s.address.endswith(beacon) for s in listeners(gateway.pid)), 60, "the gateway to listen")
        gateway.send_signal(signal.SIGTERM)
        assert finish(gateway, 8, log) == 0  # before the 10 s try would have ended
    finally:
        gateway.kill()
    said = log.read_text()
    assert f"looking for the robot: listening for the beacon of brick {host} on UDP port 3015" in said
    assert "gateway done" in said


def test_wrong_wiring_is_refused_before_anything_starts(tmp_path):
    bad = start("gateway", "--motors", "BX", log=tmp_path / "bad.log")
    assert finish(bad, 30, tmp_path / "bad.log") == 2
    assert "--motors must name two different motor ports of A, B, C, D, got 'BX'" in (tmp_path / "bad.log").read_text()
    bad = start("gateway", "--touch-port", 3, "--colour-port", 3, log=tmp_path / "bad2.log")
    assert finish(bad, 30, tmp_path / "bad2.log") == 2
    assert "three different ports" in (tmp_path / "bad2.log").read_text()
