"""Faults across real processes: a brain killed and restarted, malformed messages on every topic,
and brain and world that meet only through a router."""

import json
import os
import re
import subprocess
import threading
import time

import msgspec
import numpy as np

from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.bus import keys
from services.bus.schemas import VERSION, Array, BusError, Control, Motor, Sensors, decode, encode
from services.launch import spawn
from services.loop import brain_for, closed_loop
from services.recorder.screenshot import last_tick
from services.world.world import World
from spikinglab.bench.fuzz import examples

from .processes import (
    ROOT,
    Watcher,
    connecting,
    continued_where_lost,
    endpoint,
    finish,
    kill_mid_run,
    start,
    wait_for,
    watched_world,
    world_and_brain,
)


def test_brain_killed_mid_run_world_waits_then_continues(tmp_path):
    world, watcher, states = watched_world(tmp_path, "k", "--ticks", 6000, "--out", tmp_path)
    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    brain_args = ("--group", "k", "--listen", brain_ep, "--connect", world_ep, "--once")
    brain = start("brain", *brain_args, log=tmp_path / "brain1.log")
    try:
        kill_mid_run(brain, states, tmp_path / "world.log", "brain")
        brain = start("brain", *brain_args, log=tmp_path / "brain2.log")
        assert finish(world, 120, tmp_path / "world.log") == 0
        assert finish(brain, 30, tmp_path / "brain2.log") == 0
    finally:
        brain.kill()
        world.kill()
        watcher.close()
    continued_where_lost(tmp_path / "world.log", "brain", states, 6000)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["ticks"] == 6000
    (lost,) = metrics["brains_lost_at"]  # no --checkpoint: the brain came back without the run's learning
    assert 0 < lost < 6000 and f"brain lost at tick {lost}:" in (tmp_path / "world.log").read_text()


def garbage(tick: int) -> list[bytes]:
    """Malformed payloads: truncated, not msgpack, another version, wrong kind, wrong shapes, a
    string that is not UTF-8 (the 9-byte message that once killed three services), and seeded byte
    mutants of real messages of every kind, each checked to be one the decoder rejects."""
    good = encode(Sensors(tick=tick, names=("a",), values=Array.of(np.zeros((1, 1)))))
    raw = msgspec.msgpack.Encoder().encode
    payloads = [
        good[: len(good) // 2],
        b"\xc1\xc1 not a message",
        raw(
            {
                "kind": "sensors",
                "tick": tick,
                "version": VERSION + 7,
                "names": ["a"],
                "values": {"dtype": "<f8", "shape": [1, 0], "data": b""},
            }
        ),
        raw(
            {
                "kind": "motor",
                "tick": tick,
                "version": VERSION,
                "names": ["move"],
                "actions": {"dtype": "|u1", "shape": [1, 1], "data": b""},
            }
        ),
        encode(Control(tick=tick, command="self-destruct")),
        raw({"kind": "sensors", "tick": "now"}),
        b"\x81\xa4kind\xa2\xff\xfe",
    ]
    rng = np.random.default_rng(tick)
    for message in examples():
        payload = bytearray(encode(message))
        for where in rng.integers(0, len(payload), 3):
            payload[where] = rng.integers(0, 256)
        payloads.append(bytes(payload))
    return [p for p in payloads if rejected(p)]


def rejected(payload: bytes) -> bool:
    try:
        decode(payload)
    except BusError:
        return True
    return False


def test_malformed_messages_on_every_topic_are_rejected_and_the_run_goes_on(tmp_path):
    ticks, seed = 4000, 9
    world = World(seed=seed)
    brain = brain_for(world, load_circuit("insect"))
    closed_loop(world, brain, ticks)  # the run as it must come out, undisturbed

    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    p_world, p_brain = world_and_brain(
        tmp_path,
        ["--ticks", ticks, "--seed", seed, "--out", tmp_path],
        ["--save", tmp_path / "weights.npz", "--stats", tmp_path / "brain.json"],
    )
    p_recorder = start(
        "record", *connecting(world_ep, brain_ep), "--out", tmp_path / "run.rrd", log=tmp_path / "recorder.log"
    )
    injector = Watcher([world_ep, brain_ep], [])
    stop = threading.Event()
    topics = [
        keys.sensors("insect"),
        keys.motor("insect"),
        keys.control("insect"),
        keys.world_state("insect"),
        keys.brain_state("insect"),
        keys.world_map("insect"),
    ]
    publishers = {k: injector.session.declare_publisher(k) for k in topics}
    # well formed, but not for this run (they do not name it): motor for no agents and for two
    misfits = [
        encode(Motor(tick=t, names=("rotate", "move"), actions=Array.of(np.ones((a, 2), np.uint8))))
        for t in range(0, ticks, 97)
        for a in (0, 2)
    ]

    def inject():
        k = 0
        while not stop.is_set():
            payloads = garbage(k)
            for pub in publishers.values():
                pub.put(payloads[k % len(payloads)], attachment=b"injector")
            publishers[keys.motor("insect")].put(misfits[k % len(misfits)], attachment=b"injector")
            k += 1
            time.sleep(0.002)

    thread = threading.Thread(target=inject)
    thread.start()
    try:
        assert finish(p_world, 120, tmp_path / "world.log") == 0
        assert finish(p_brain, 30, tmp_path / "brain.log") == 0
        assert finish(p_recorder, 60, tmp_path / "recorder.log") == 0
    finally:
        stop.set()
        thread.join()
        injector.close()
        for process in (p_world, p_brain, p_recorder):
            process.kill()
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    world_rejected = metrics["rejected_messages"][keys.motor("insect")]
    assert world_rejected["not a message"] > 10 and world_rejected["another run"] > 10, world_rejected
    brain_rejected = json.loads((tmp_path / "brain.json").read_text())["rejected_messages"]
    assert sum(brain_rejected[keys.sensors("insect")].values()) > 10
    assert sum(brain_rejected[keys.control("insect")].values()) > 10
    assert "from injector" in (tmp_path / "brain.log").read_text()
    recorder_log = (tmp_path / "recorder.log").read_text()
    assert "from injector" in recorder_log and keys.world_map("insect") in recorder_log
    # nothing of them was applied: the run is exactly the undisturbed one, and the recording whole
    assert metrics["collisions"] == world.metrics.collisions.tolist()
    assert metrics["food"] == world.metrics.food.tolist()
    np.testing.assert_array_equal(load_weights(tmp_path / "weights.npz", brain.circuit), brain.engine.get_weights())
    assert last_tick(tmp_path / "run.rrd") == ticks - 1  # poses through tick 3999, and "run ended at tick 4000" there


def test_brain_and_world_meet_only_through_a_router(tmp_path):
    router_ep = endpoint(tmp_path, "router")
    router = start("router", "--listen", router_ep, log=tmp_path / "router.log")
    try:
        world = start("world", "--connect", router_ep, "--ticks", 1500, "--out", tmp_path, log=tmp_path / "world.log")
        brain = start("brain", "--connect", router_ep, "--once", log=tmp_path / "brain.log")
        assert finish(world, 60, tmp_path / "world.log") == 0
        assert finish(brain, 30, tmp_path / "brain.log") == 0
    finally:
        router.kill()
    assert json.loads((tmp_path / "metrics.json").read_text())["ticks"] == 1500


def test_clients_started_before_their_router_wait_for_it(tmp_path):
    """A launch starts its processes at once: a client (the secured bus's services are clients)
    must not fail because its router is still starting."""
    (tmp_path / "client.json5").write_text('{mode: "client"}\n')
    router_ep = endpoint(tmp_path, "router")
    client = ("--connect", router_ep, "--zenoh-config", tmp_path / "client.json5")
    world = start("world", *client, "--ticks", 1500, "--out", tmp_path, log=tmp_path / "world.log")
    brain = start("brain", *client, "--once", log=tmp_path / "brain.log")
    time.sleep(2.0)
    router = start("router", "--listen", router_ep, log=tmp_path / "router.log")
    try:
        assert finish(world, 60, tmp_path / "world.log") == 0
        assert finish(brain, 30, tmp_path / "brain.log") == 0
    finally:
        router.kill()
        world.kill()
        brain.kill()
    assert json.loads((tmp_path / "metrics.json").read_text())["ticks"] == 1500


def test_a_world_whose_terminal_is_gone_still_writes_its_result(tmp_path):
    """A launcher killed with kill -9 closes the pipe that shows its services' output; the world's
    progress bar then writes into nothing, and the world, sent SIGTERM with it, must still write
    the ticks done (it died of the broken pipe, its metrics lost)."""
    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    world = spawn(
        "world",
        ["--listen", world_ep, "--ticks", 1_000_000, "--progress", "--out", tmp_path],
        subprocess.PIPE,
        cwd=ROOT,
    )
    brain = start("brain", "--listen", brain_ep, "--connect", world_ep, "--once", log=tmp_path / "brain.log")
    try:
        assert world.stdout is not None  # PIPE
        shown = b""
        while not re.search(rb"\d+(\.\d+)?k/1\.00M", shown):  # the bar past 1,000 ticks (1.50k/1.00M)
            chunk = os.read(world.stdout.fileno(), 4096)
            assert chunk, f"the world ended: {shown.decode(errors='replace')[-2000:]}"
            shown += chunk
        world.stdout.close()
        time.sleep(2)  # the bar's next updates meet the closed pipe
        assert world.poll() is None, "the world died of the closed pipe"
        world.terminate()
        assert finish(world, 60) == 130
    finally:
        world.kill()
        brain.kill()
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["partial"] and 1000 < metrics["ticks"] < 1_000_000


def test_a_brain_stopped_mid_run_writes_its_stats(tmp_path):
    """SIGTERM before any run's end: the brain's --stats file still lists what it rejected (a forged
    message of an older schema version on its sensors key), not the log alone."""
    brain_ep, stats, log = endpoint(tmp_path, "brain"), tmp_path / "brain.json", tmp_path / "brain.log"
    brain = start("brain", "--listen", brain_ep, "--group", tmp_path.name, "--stats", stats, log=log)
    forger = Watcher([brain_ep], [])
    try:
        wait_for(lambda: "brain ready" in log.read_text(), 180, "the brain to be ready")
        sensors = forger.session.declare_publisher(keys.sensors(tmp_path.name))
        wait_for(lambda: matched(sensors), 30, "the brain to subscribe to its sensors")
        old = {"kind": "sensors", "tick": 1, "version": 7, "values": {"dtype": "<f8", "shape": [1, 1], "data": b""}}
        sensors.put(msgspec.msgpack.encode(old), attachment=b"forger")
        wait_for(lambda: "rejected message on" in log.read_text(), 30, "the brain to reject it")
        brain.terminate()
        assert finish(brain, 60, log) == 130
    finally:
        forger.close()
        brain.kill()
    written = json.loads(stats.read_text())
    assert written["rejected_messages"] == {
        keys.sensors(tmp_path.name): {f"schema version 7, this program speaks {VERSION}": 1}
    }
    assert written["ticks"] == 0


def matched(publisher) -> bool:
    """Whether a subscriber for the publisher's key is known (Outbox.matched's reading)."""
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))
