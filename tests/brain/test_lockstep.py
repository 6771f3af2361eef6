"""The lock-step brain's view of its world on a real bus, in this process: when a --once brain gives
up on a world gone for good, and when a sharded world's end of the run is taken (lockstep.py)."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

import services.brain.lockstep as lockstep
from services.brain.checkpoint import load_weights, save_weights
from services.brain.circuit import load_circuit
from services.brain.lockstep import LockStep
from services.brain.node import BrainNode
from services.brain.service import BrainConfig, parser
from services.bus import keys
from services.bus.config import make_config
from services.bus.schemas import Array, Control, Message, Motor, Sensors, decode, encode
from services.bus.transport import QUIET_S, Bus
from services.options import config_from
from services.vocabulary import INSECT_SENSORS

from ..processes import endpoint, start, wait_for

GROUP = "ls"
GONE_S = 0.3  # lockstep.GONE_S here: the wait itself is what is tested, not its length
CIRCUIT = load_circuit("insect")


@pytest.fixture
def router(tmp_path):
    at = endpoint(tmp_path, "router")
    process = start("router", "--listen", at, log=tmp_path / "router.log")
    yield at
    process.kill()
    process.wait()


class Sessions:
    """Zenoh sessions of this test and the brains' buses on them, closed at its end."""

    def __init__(self):
        self.opened: list[zenoh.Session] = []
        self.buses: list[Bus] = []

    def open(self, connect=(), listen=()) -> zenoh.Session:
        session = zenoh.open(make_config(connect=connect, listen=listen))
        self.opened.append(session)
        return session

    def brain(self, connect=(), listen=(), options=(), quiet_s: float = QUIET_S, once: bool = True) -> LockStep:
        """A lock-step brain (--once unless not `once`, with `options`) on a session of its own, as
        the brain service makes it; `quiet_s`: how long the run served must be silent before another
        may start."""
        args = parser().parse_args([*(["--once"] if once else []), "--group", GROUP, *map(str, options)])
        config = config_from(args, BrainConfig)
        bus = Bus(self.open(connect, listen), config.bus.group, keys.brain_service(config.shard))
        self.buses.append(bus)
        return LockStep(config, bus, lambda: BrainNode(CIRCUIT, world_shards=config.world_shards, quiet_s=quiet_s))


@pytest.fixture
def sessions():
    made = Sessions()
    yield made
    for bus in made.buses:
        bus.close()  # its inboxes' threads first, then its session
    for session in made.opened:
        if not session.is_closed():
            session.close()


class World:
    """What a world is to the brain: its liveliness token (as `service`), which can leave and come
    back, and what it puts on the control key."""

    def __init__(self, session: zenoh.Session, service: str = "world"):
        self.session, self.service, self.token = session, service, None
        self.control = session.declare_publisher(keys.control(GROUP))

    def join(self) -> None:
        self.token = self.session.liveliness().declare_token(keys.alive(GROUP, self.service))

    def leave(self) -> None:
        assert self.token is not None
        self.token.undeclare()
        self.token = None

    def end(self, run: str, tick: int) -> None:
        self.control.put(encode(Control(tick=tick, command="end", run=run)), attachment=b"world@1")


def reading(tick: int, first: int = 0, run: str = "r1", checkpoint: bool = False) -> Sensors:
    """Sensors of one agent, agent `first` of the population, sensing nothing."""
    values = Array.of(np.full((1, len(INSECT_SENSORS)), np.nan))
    return Sensors(tick=tick, names=INSECT_SENSORS, values=values, run=run, first=first, checkpoint=checkpoint)


def serve(brain: LockStep, ticks: range, first: int = 0, run: str = "r1", checkpoint: bool = False) -> None:
    """The reading of agent `first` for each of `ticks`, answered."""
    for tick in ticks:
        message = reading(tick, first, run, checkpoint)
        brain.serve(message, brain.starts_run(message))
    assert brain.progress()[0] == run


def stays_false(check, seconds: float) -> bool:
    """Whether `check()` stays false for `seconds`, asked as the brain's loop asks it."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if check():
            return False
        time.sleep(0.02)
    return True


def brain_and_world(sessions, router) -> tuple[LockStep, World]:
    """A brain on `router` and a world that joined it, each seen by the other."""
    brain = sessions.brain(connect=[router])
    world = World(sessions.open(connect=[router]))
    wait_for(lambda: list(brain.bus.session.info.routers_zid()), 10, "the brain to reach the router")
    world.join()
    wait_for(brain.world_alive, 10, "the brain to see the world")
    return brain, world


def test_a_once_brain_gives_up_on_a_world_gone_for_good_only_after_gone_s_on_a_router(router, sessions, monkeypatch):
    """Not while there is no run, nor while the world is on the bus, nor while the run's learning is
    not kept; then after GONE_S on a router; a world back on the bus resets the wait."""
    monkeypatch.setattr(lockstep, "GONE_S", GONE_S)
    served, world = brain_and_world(sessions, router)
    assert not served.world_gone_for_good()  # no run yet
    serve(served, range(5))
    assert stays_false(served.world_gone_for_good, 2 * GONE_S)  # the world is on the bus
    world.leave()
    wait_for(lambda: not served.world_alive(), 10, "the brain to see the world leave")
    assert stays_false(served.world_gone_for_good, 2 * GONE_S)  # its learning not kept: not known to have stopped
    served.keep_learning("its world left the bus")
    gone_at = time.monotonic()
    wait_for(served.world_gone_for_good, 10, "the brain to give up on its world")
    assert time.monotonic() - gone_at >= GONE_S
    world.join()  # it came back: the wait starts again once it leaves again
    wait_for(served.world_alive, 10, "the brain to see the world back")
    assert not served.world_gone_for_good()
    world.leave()
    wait_for(lambda: not served.world_alive(), 10, "the brain to see the world leave")
    gone_at = time.monotonic()
    wait_for(served.world_gone_for_good, 10, "the brain to give up on its world again")
    assert time.monotonic() - gone_at >= GONE_S


def test_a_once_brain_waits_for_a_world_that_kept_a_checkpoint_and_for_one_it_never_saw(router, sessions, monkeypatch):
    """A world that keeps checkpoints of the run may resume it; a run with no world seen (a
    gateway's) has no world to give up on."""
    monkeypatch.setattr(lockstep, "GONE_S", GONE_S)
    resumable, world = brain_and_world(sessions, router)
    serve(resumable, range(5))
    serve(resumable, range(5, 6), checkpoint=True)  # the world kept a checkpoint at tick 5
    world.leave()
    wait_for(lambda: not resumable.world_alive(), 10, "the brain to see the world leave")
    resumable.keep_learning("its world left the bus")
    assert stays_false(resumable.world_gone_for_good, 3 * GONE_S)

    unseen = sessions.brain(connect=[router], options=["--group", "ls-gateway"])
    wait_for(lambda: list(unseen.bus.session.info.routers_zid()), 10, "the brain to reach the router")
    serve(unseen, range(5))
    unseen.keep_learning("its world left the bus")
    assert stays_false(unseen.world_gone_for_good, 3 * GONE_S)


def test_a_once_brain_of_peers_only_waits_for_its_world(tmp_path, sessions, monkeypatch):
    """With no router, the world is the brain's link to the bus: it may come back, so no wait ends."""
    monkeypatch.setattr(lockstep, "GONE_S", GONE_S)
    at = endpoint(tmp_path, "brain")
    served = sessions.brain(listen=[at])
    world = World(sessions.open(connect=[at]))
    world.join()
    wait_for(served.world_alive, 10, "the brain to see the world")
    serve(served, range(5))
    world.leave()
    wait_for(lambda: not served.world_alive(), 10, "the brain to see the world leave")
    served.keep_learning("its world left the bus")
    assert stays_false(served.world_gone_for_good, 3 * GONE_S)


def sharded_run(sessions, router, options: list, **brain) -> tuple[LockStep, World, World]:
    """A brain of --world-shards 2 (and `options`) on `router`, world shards 1 and 2 joined, run r1
    served to tick 9 of the lead's piece (agent 0) and tick 19 of world shard 2's (agent 1), ahead."""
    served = sessions.brain(connect=[router], options=["--world-shards", 2, *options], **brain)
    lead = World(sessions.open(connect=[router]))
    other = World(sessions.open(connect=[router]), "world-2of2")
    for world in (lead, other):
        world.join()
    wait_for(lambda: all(w.alive for w in served.worlds), 10, "the brain to see both world shards")
    serve(served, range(10), first=0)
    serve(served, range(20), first=1)
    return served, lead, other


@pytest.mark.parametrize("stops", ["done", "leaves"])
def test_a_sharded_worlds_end_is_taken_once_every_other_world_shard_has_stopped(
    router, sessions, tmp_path, caplog, stops
):
    """The lead's end of the run names its own tick, before the last of the piece that world shard
    2 sends: the brain holds it, answers world shard 2's next tick, and ends the run with it once
    that shard has finished its ticks (its -done token), its weights saved to --save, or left the
    bus without it (lost: the weights kept as a run that stopped without its end, not saved to
    --save). Another run's end is refused; a second end of the run changes nothing."""
    served, lead, other = sharded_run(sessions, router, ["--save", tmp_path / "weights.npz"])
    lead.end("r2", 30)
    lead.end("r1", 9)
    lead.end("r1", 12)
    ended: list[bool] = []  # what take_orders said each time: True would end the run
    wait_for(lambda: ended.append(served.take_orders()) or served.control.rejections(), 10, "r2's end refused")
    assert not any(ended) and not served.take_orders()  # world shard 2 is stepping
    assert served.control.rejections() == {keys.control(GROUP): {"does not fit the run": 1}}  # r2's only
    lead.leave()
    wait_for(lambda: not served.worlds[0].alive, 10, "the brain to see the lead leave")
    assert not served.take_orders()  # world shard 2 is still stepping
    serve(served, range(20, 21), first=1)  # and its next tick is answered
    assert served.progress() == ("r1", (9, 20)) and not (tmp_path / "weights.npz").exists()
    done = World(other.session, "world-2of2-done")  # kept: a token dropped is undeclared
    if stops == "done":
        done.join()
    else:
        other.leave()
    with caplog.at_level("INFO", logger="spikinglab.brain"):
        wait_for(served.take_orders, 10, "the brain to end the run")
    assert "run ended at tick 9 (world shard 1's; the last tick of each piece served: 9, 20)" in caplog.text
    kept = list(tmp_path.glob("weights-*"))  # kept as a run that stopped without its end
    if stops == "done":
        assert load_weights(tmp_path / "weights.npz", CIRCUIT).shape[0] == 2  # both pieces' agents
        assert not kept and "left the bus before the end of its ticks" not in caplog.text
    else:
        assert not (tmp_path / "weights.npz").exists() and len(kept) == 1
        assert load_weights(kept[0], CIRCUIT).shape[0] == 2
        why = "(world-2of2 left the bus before the end of its ticks): its weights so far saved to"
        assert f"run r1 ended at tick 9 without a whole result {why}" in caplog.text


def test_a_world_shards_done_token_heard_just_after_its_leaving_still_counts(router, sessions, tmp_path):
    """World shard 2 ends its ticks after the lead's end: it says it is done and leaves within a
    millisecond, and the brain's two watches may hear the leaving first (seen in CI). A -done token
    heard within DONE_GRACE_S of the end still makes the run whole: --save written, none kept."""
    save = tmp_path / "weights.npz"
    served, lead, other = sharded_run(sessions, router, ["--save", save])
    lead.end("r1", 9)
    other.leave()
    wait_for(lambda: not served.worlds[1].alive, 10, "the brain to see world shard 2 leave")
    done = World(other.session, "world-2of2-done")
    late = threading.Timer(0.2, done.join)  # its -done token, heard a moment after
    late.start()
    wait_for(served.take_orders, 10, "the brain to end the run")
    late.join()
    assert save.exists() and not list(tmp_path.glob("weights-*")) and served.exit_code == 0


def test_a_world_shard_never_seen_is_named_as_perhaps_not_the_worlds(router, sessions, tmp_path, caplog):
    """A brain of --world-shards 2 on a world of one shard (a slip by hand): the shard it waited for
    was never on the bus, and its end says so rather than that the shard left."""
    served = sessions.brain(connect=[router], options=["--world-shards", 2, "--save", tmp_path / "weights.npz"])
    lead = World(sessions.open(connect=[router]))
    lead.join()
    wait_for(lambda: served.worlds[0].alive, 10, "the brain to see the world")
    serve(served, range(10), first=0)
    with caplog.at_level("INFO", logger="spikinglab.brain"):
        lead.end("r1", 9)
        wait_for(served.take_orders, 10, "the brain to end the run")
    assert "without a whole result (world-2of2 was never on the bus (--world-shards 2: the world's?))" in caplog.text


def test_each_run_served_judges_its_own_world_shards(router, sessions, tmp_path, caplog):
    """A brain that serves run after run (no --once): a world shard 2 that said it had finished r1
    does not cover r2's shard 2, which leaves without; r3's leaves before the brain's first piece
    of r3. Each lost run is kept beside --save; --save keeps r1, the whole one."""
    save = tmp_path / "weights.npz"
    served, lead, other = sharded_run(sessions, router, ["--save", save], once=False)
    done = World(other.session, "world-2of2-done")
    done.join()
    lead.end("r1", 9)
    wait_for(lambda: served.take_orders() or save.exists(), 10, "r1 to end")
    other.leave()
    done.leave()
    wait_for(lambda: not served.worlds[1].alive and not served.done[0].alive, 10, "the brain to see r1's shard 2 go")
    second = World(sessions.open(connect=[router]), "world-2of2")
    second.join()
    wait_for(lambda: served.worlds[1].alive, 10, "the brain to see r2's shard 2")
    serve(served, range(10), first=0, run="r2")
    serve(served, range(12), first=1, run="r2")
    second.leave()
    lead.end("r2", 9)
    wait_for(lambda: served.take_orders() or list(tmp_path.glob("weights-r2-*")), 10, "r2 to end, kept")
    third = World(sessions.open(connect=[router]), "world-2of2")
    third.join()
    wait_for(lambda: served.worlds[1].alive, 10, "the brain to see r3's shard 2")
    third.leave()
    wait_for(lambda: not served.worlds[1].alive, 10, "the brain to see r3's shard 2 go")
    with caplog.at_level("INFO", logger="spikinglab.brain"):
        serve(served, range(5), first=0, run="r3")
        lead.end("r3", 4)
        wait_for(lambda: served.take_orders() or list(tmp_path.glob("weights-r3-*")), 10, "r3 to end, kept")
    assert "world-2of2 left the bus before the end of its ticks" in caplog.text
    assert load_weights(save, CIRCUIT).shape[0] == 2  # r1's two pieces, not overwritten since
    assert [p.name for p in sorted(tmp_path.glob("weights-*"))] == ["weights-r2-tick10.npz", "weights-r3-tick5.npz"]


def test_a_world_shard_on_the_bus_that_sends_nothing_for_gone_s_holds_the_end_no_longer(
    router, sessions, tmp_path, monkeypatch
):
    """World shard 2 stuck (or a forged token of it): on the bus, never done, silent."""
    monkeypatch.setattr(lockstep, "GONE_S", GONE_S)
    served, lead, other = sharded_run(sessions, router, ["--save", tmp_path / "weights.npz"])
    heard_at = time.monotonic()
    lead.end("r1", 9)
    wait_for(served.take_orders, 10, "the brain to end the run")
    assert time.monotonic() - heard_at >= GONE_S and other.token is not None
    assert load_weights(tmp_path / "weights.npz", CIRCUIT).shape[0] == 2


def test_a_held_end_is_taken_when_another_run_starts_and_a_once_brain_serves_no_other(
    router, sessions, tmp_path, caplog
):
    """World shard 2 stays on the bus, silent (stuck): the lead's end of the run is held until the
    first sensors of another run come, the run served gone quiet; the run ends with it then, and a
    --once brain ends there, the other run unanswered."""
    served, lead, other = sharded_run(sessions, router, ["--save", tmp_path / "weights.npz"], quiet_s=0.2)
    lead.end("r1", 9)
    lead.leave()
    answers: list[Message] = []
    watch = other.session.declare_subscriber(keys.motor(GROUP), lambda s: answers.append(decode(s.payload.to_bytes())))
    returned: list[int] = []
    brain = threading.Thread(target=lambda: returned.append(served.run()), daemon=True)
    with caplog.at_level("INFO", logger="spikinglab.brain"):
        brain.start()
        time.sleep(0.5)  # the run served goes quiet
        assert brain.is_alive() and not (tmp_path / "weights.npz").exists()  # its end held: world shard 2 is on
        other.session.put(keys.sensors(GROUP), encode(reading(0, run="r2")))
        brain.join(10)
    assert returned == [0] and "run ended at tick 9" in caplog.text
    assert load_weights(tmp_path / "weights.npz", CIRCUIT).shape[0] == 2
    time.sleep(0.3)
    assert not [a for a in answers if isinstance(a, Motor) and a.run == "r2"]
    watch.undeclare()


def test_an_interrupt_while_the_end_is_saved_saves_it_again(router, sessions, tmp_path, monkeypatch):
    """SIGTERM (as launch sends it) lands while the run's end writes --save: the end is saved once
    more on the way out, not kept as learning of a run that stopped without its end."""
    served, world = brain_and_world(sessions, router)
    served.config = dataclasses.replace(served.config, save=tmp_path / "weights.npz")
    serve(served, range(5))
    saves: list[Path] = []

    def interrupted_once(path, *args, **kwargs):
        saves.append(path)
        if len(saves) == 1:
            raise KeyboardInterrupt
        save_weights(path, *args, **kwargs)

    monkeypatch.setattr(lockstep, "save_weights", interrupted_once)
    world.end("r1", 5)
    with pytest.raises(KeyboardInterrupt):
        served.run()
    assert saves == [tmp_path / "weights.npz"] * 2
    assert load_weights(tmp_path / "weights.npz", CIRCUIT).shape[0] == 1
    assert not list(tmp_path.glob("weights-*"))


def test_a_brain_built_for_a_run_but_not_stepped_has_no_learning_to_keep(sessions, tmp_path):
    """Ctrl-C as the brain compiles its engine for a run's first sensors is taken once the compile
    is over (services/interrupts.py), before the run's first step: nothing was learnt, so nothing
    is kept (it was saved as weights-None-tick0.npz, of no run)."""
    brain = sessions.brain(options=["--save", tmp_path / "weights.npz"])
    brain.node.start(reading(0))  # answer() builds the brain, then names the run and steps
    assert not brain.unsaved()
    serve(brain, range(1))
    assert brain.unsaved()


def test_a_stepped_piece_is_learning_to_keep_while_another_is_built_but_not_stepped(sessions):
    """A brain serving pieces of 2 world shards: world shard 2's piece has stepped, world shard 1's
    is built but not stepped (an interrupt landed just after its compile): there is learning to keep."""
    brain = sessions.brain(options=["--world-shards", 2])
    serve(brain, range(3), first=4)
    brain.node_for(reading(0), False).start(reading(0))
    assert brain.unsaved()


def test_an_end_that_came_while_the_brain_was_busy_is_taken_when_it_is_interrupted(
    router, sessions, tmp_path, monkeypatch
):
    """The world ends the run while the brain is busy (compiling a kernel, which an interrupt waits
    for), then launch stops the brain: the end waiting in its inbox is taken, its weights saved to
    --save, not kept as the learning of a run that stopped without its end."""
    served, world = brain_and_world(sessions, router)
    served.config = dataclasses.replace(served.config, save=tmp_path / "weights.npz")
    serve(served, range(5))
    heard = threading.Event()  # on the brain's session: the end has reached it
    listener = served.bus.session.declare_subscriber(keys.control(GROUP), lambda sample: heard.set())
    world.end("r1", 5)

    def busy_then_interrupted(timeout=None):
        assert heard.wait(10), "the end never reached the brain's session"
        time.sleep(0.1)  # and its control inbox, on the same session
        raise KeyboardInterrupt

    monkeypatch.setattr(served.sensors, "get", busy_then_interrupted)
    with pytest.raises(KeyboardInterrupt):
        served.run()
    listener.undeclare()
    assert load_weights(tmp_path / "weights.npz", CIRCUIT).shape[0] == 1
    assert not list(tmp_path.glob("weights-*"))
