"""A sharded world: N world processes each step a slice of the population, as one world would."""

import json
import re
import signal
import subprocess
import sys
import time
from contextlib import contextmanager

import numpy as np
import pytest

from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.bus import keys
from services.bus.schemas import Array, WorldState, encode
from services.loop import brain_for, closed_loop
from services.options import shard_slice, shards_meet
from services.world.options import WorldOptions, world_from
from services.world.shards import merge_metrics
from services.world.world import SENSORS

from .processes import Watcher, endpoint, finish, logged, start, wait_for
from .recordings import read

TICKS, SEED, AGENTS = 3000, 3, 7  # 7 agents: world slices 0-2 and 3-6, brain slices 0-1, 2-3 and 4-6


def options(tmp_path, agents=AGENTS, shared=False) -> WorldOptions:
    study = tmp_path / "study.csv"
    np.savetxt(study, np.c_[1 - 0.05 * np.arange(agents)], delimiter=",", header="move_step", comments="")
    return WorldOptions(
        ticks=TICKS,
        seed=SEED,
        agents=agents,
        shared=shared,
        preset="paper",
        map=None,
        no_training=False,
        learned_after=5000,
        params=study,
    )


def test_a_sliced_world_steps_the_same_insects_as_the_whole(tmp_path):
    circuit = load_circuit("insect").with_learning_rate(0.04)
    whole = world_from(options(tmp_path))
    brain = brain_for(whole, circuit)
    closed_loop(whole, brain, TICKS)
    slices = [world_from(options(tmp_path), shard=(i, 2)) for i in (1, 2)]
    assert [w.agents for w in slices] == [3, 4] and list(slices[1].numbers) == [3, 4, 5, 6]
    for world in slices:
        closed_loop(world, brain_for(world, circuit), TICKS)
    assert sum(whole.metrics.collisions) > 0
    for name in ("collisions", "food", "distance", "resets", "learned_at"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(w.metrics, name) for w in slices]), getattr(whole.metrics, name), err_msg=name
        )
    np.testing.assert_array_equal(np.concatenate([w.pos for w in slices]), whole.pos)


@pytest.mark.parametrize("agents", [1, 2, 7, 10, 101])
def test_world_and_brain_shards_meet_in_pieces_that_cover_each_slice_once(agents):
    for n in range(1, min(agents, 5) + 1):
        for m in range(1, min(agents, 5) + 1):
            meets = {(i, j): shards_meet(agents, (i, n), (j, m)) for i in range(1, n + 1) for j in range(1, m + 1)}
            for i in range(1, n + 1):  # a world shard's pieces, brain shard by brain shard, make its slice
                pieces = [meets[i, j] for j in range(1, m + 1) if meets[i, j][0] < meets[i, j][1]]
                assert [a for lo, hi in pieces for a in range(lo, hi)] == list(range(*shard_slice(agents, (i, n))))
            for j in range(1, m + 1):  # and a brain shard's, world shard by world shard, its own
                pieces = [meets[i, j] for i in range(1, n + 1) if meets[i, j][0] < meets[i, j][1]]
                assert [a for lo, hi in pieces for a in range(lo, hi)] == list(range(*shard_slice(agents, (j, m))))


def test_a_shared_arena_is_not_sharded(tmp_path):
    with pytest.raises(ValueError, match="with --shared: the insects of a shared arena meet"):
        world_from(options(tmp_path, shared=True), shard=(1, 2))
    with pytest.raises(ValueError, match="at most one shard per agent"):
        world_from(options(tmp_path, agents=2), shard=(1, 3))


def start_shards(tmp_path, bus: tuple, made, brains: int, *world_options) -> tuple[list, list]:
    """2 world shards of the population in `made` and `brains` brain shards (each saving its weights),
    on `bus`, with the world shards' further options."""
    world = ("--ticks", TICKS, "--seed", SEED, "--agents", AGENTS, "--params", made.params, "--shards", brains)
    worlds = [
        start(
            "world",
            *bus,
            *world,
            *world_options,
            "--shard",
            f"{i}/2",
            "--out",
            tmp_path,
            log=tmp_path / f"world{i}.log",
        )
        for i in (1, 2)
    ]
    brain = ("--world-shards", 2, "--once", "--a-plus", 0.04, "--params", made.params)
    shards = [
        start(
            "brain",
            *bus,
            *brain,
            "--shard",
            f"{j}/{brains}",
            "--save",
            tmp_path / f"weights{j}.npz",
            log=tmp_path / f"brain{j}.log",
        )
        for j in range(1, brains + 1)
    ]
    return worlds, shards


@pytest.mark.parametrize("brains", [1, 3])
def test_two_world_shards_and_brain_shards_run_bit_for_bit_as_one_process(tmp_path, brains):
    """World slices 0-2 and 3-6; with 3 brain shards, shard 2/3 (agents 2-3) serves a piece of each."""
    made = options(tmp_path)
    bus = ("--group", "ws", "--connect", endpoint(tmp_path, "router"))
    router = start("router", "--listen", endpoint(tmp_path, "router"), log=tmp_path / "router.log")
    worlds, shards = start_shards(tmp_path, bus, made, brains)
    try:
        for i, process in enumerate(worlds, 1):
            assert finish(process, 120, tmp_path / f"world{i}.log") == 0
        for j, process in enumerate(shards, 1):
            assert finish(process, 30, tmp_path / f"brain{j}.log") == 0
    finally:
        for process in (*worlds, *shards, router):
            process.kill()
    circuit = load_circuit("insect").with_learning_rate(0.04)
    alone = world_from(made)
    brain = brain_for(alone, circuit)
    closed_loop(alone, brain, TICKS)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["ticks"] == TICKS and metrics["agents"] == AGENTS and metrics["world_shards"] == 2
    assert sum(metrics["collisions"]) > 0 and not metrics["partial"]
    assert metrics["collisions"] == alone.metrics.collisions.tolist()
    assert metrics["food"] == alone.metrics.food.tolist()
    assert metrics["distance"] == np.round(alone.metrics.distance, 3).tolist()
    assert metrics["learning_time"] == [int(t) if t >= 0 else None for t in alone.metrics.learned_at]
    weights = np.concatenate([load_weights(tmp_path / f"weights{j}.npz", circuit) for j in range(1, brains + 1)])
    np.testing.assert_array_equal(weights, brain.engine.get_weights())  # bit for bit
    runs = {logged((tmp_path / f"world{i}.log").read_text(), r"run (\w+): \d+ ticks").group(1) for i in (1, 2)}
    assert len(runs) == 1  # one run id
    for j in range(1, brains + 1):
        assert "keeps checkpoints" not in (tmp_path / f"brain{j}.log").read_text()  # no shard's first tick says so
    logs = [(tmp_path / name).read_text() for name in ("world1.log", *(f"brain{j}.log" for j in range(1, brains + 1)))]
    assert all("-done left the bus" not in log for log in logs)  # a shard's "finished" token dropped: no warning


@contextmanager
def shards_on_a_router(tmp_path, group: str, brains: int, ticks: int):
    """A router, and on it (group `group`) 2 world shards of `ticks` ticks and `brains` brain shards
    (start_shards); (world shards, brain shards), every process killed on leaving."""
    bus = ("--group", group, "--connect", endpoint(tmp_path, "router"))
    router = start("router", "--listen", endpoint(tmp_path, "router"), log=tmp_path / "router.log")
    worlds, shards = start_shards(tmp_path, bus, options(tmp_path), brains, "--ticks", ticks)
    try:
        yield worlds, shards
    finally:
        for process in (*worlds, *shards, router):
            process.kill()


def serving(tmp_path, brains: int) -> None:
    """Until each of the brain shards, logging to brain<j>.log in `tmp_path`, serves its first piece."""
    for j in range(1, brains + 1):
        log = tmp_path / f"brain{j}.log"
        wait_for(lambda log=log: "brain for" in log.read_text(), 120, f"{log.name} to say it serves")


def test_a_world_shard_whose_options_differ_from_the_leads_says_which_and_stays_off(tmp_path):
    """World shard 2 started with another seed, tick count and map than shard 1: its slice would not
    be of the lead's population, so it names each difference and ends (exit 2) before it joins;
    the lead keeps waiting for a shard 2 and says so. A second shard 1 is refused too."""
    made = options(tmp_path)
    own_map = tmp_path / "own.map"
    own_map.write_text("#####\n#S..#\n#####\n")
    bus = ("--group", "wd", "--connect", endpoint(tmp_path, "router"))
    router = start("router", "--listen", endpoint(tmp_path, "router"), log=tmp_path / "router.log")
    common = ("--agents", AGENTS, "--params", made.params, "--shards", 1)
    lead = start("world", *bus, *common, "--seed", 5, "--ticks", 2000, "--shard", "1/2", log=tmp_path / "world1.log")
    other = ("--seed", 7, "--ticks", 3000, "--map", own_map, "--shard", "2/2")
    follower = start("world", *bus, *common, *other, log=tmp_path / "world2.log")
    try:
        assert finish(follower, 60, tmp_path / "world2.log") == 2
        said = (tmp_path / "world2.log").read_text()
        for difference in (
            "--seed 7 here, 5 at world shard 1",
            "--ticks 3000 here, 2000 at world shard 1",
            "--map (its file's SHA-256) ",
        ):
            assert difference in said
        assert "Traceback" not in said
        wait_for(
            lambda: "waiting for world shard(s) world-2of2 to join" in (tmp_path / "world1.log").read_text(),
            30,
            "the lead to say whom it waits for",
        )
        assert lead.poll() is None
        again = start(
            "world", *bus, *common, "--seed", 5, "--ticks", 2000, "--shard", "1/2", log=tmp_path / "again.log"
        )
        assert finish(again, 60, tmp_path / "again.log") == 2  # a second lead would name a second run
        assert "world shard 1/2 is on the bus of group wd already" in (tmp_path / "again.log").read_text()
    finally:
        for process in (lead, follower, router):
            process.kill()


def test_a_second_copy_of_a_world_shard_waiting_for_its_lead_stays_off(tmp_path):
    """World shard 2 started twice before the lead: the copy finds the first waiting for the lead to
    name the run and ends (exit 2) before it joins, where both would have joined; the first joins
    the lead's run, which runs to its end with a result for every insect."""
    made = options(tmp_path)
    bus = ("--group", "wt", "--connect", endpoint(tmp_path, "router"))
    router = start("router", "--listen", endpoint(tmp_path, "router"), log=tmp_path / "router.log")
    world = ("--ticks", TICKS, "--seed", SEED, "--agents", AGENTS, "--params", made.params, "--shards", 1)
    first = start("world", *bus, *world, "--shard", "2/2", "--out", tmp_path, log=tmp_path / "world2.log")
    processes = [router, first]
    try:
        wait_for(
            lambda: "waiting for world shard 1/2 to name the run" in (tmp_path / "world2.log").read_text(),
            60,
            "world shard 2 to wait for its lead",
        )
        copy = start("world", *bus, *world, "--shard", "2/2", "--out", tmp_path, log=tmp_path / "copy.log")
        processes.append(copy)
        assert finish(copy, 60, tmp_path / "copy.log") == 2
        said = (tmp_path / "copy.log").read_text()
        assert "world shard 2/2 is on the bus of group wt already, waiting to join: each shard is one process" in said
        lead = start("world", *bus, *world, "--shard", "1/2", "--out", tmp_path, log=tmp_path / "world1.log")
        brain = start("brain", *bus, "--world-shards", 2, "--once", "--params", made.params, log=tmp_path / "brain.log")
        processes += [lead, brain]
        assert finish(lead, 120, tmp_path / "world1.log") == 0
        assert finish(first, 60, tmp_path / "world2.log") == 0
        assert finish(brain, 30, tmp_path / "brain.log") == 0
    finally:
        for process in processes:
            process.kill()
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["agents"] == AGENTS and metrics["ticks"] == TICKS and not metrics["partial"]
    for log in ("world1.log", "brain.log"):  # a shard's waiting token is no service coming or leaving
        assert "-waiting-" not in (tmp_path / log).read_text()


def test_ctrl_c_at_a_lead_still_waiting_for_its_shards_says_it_stopped(tmp_path):
    """Before any run: exit 130 and a line that says so, not a log that ends on "waiting"."""
    router = start("router", "--listen", endpoint(tmp_path, "router"), log=tmp_path / "router.log")
    bus = ("--group", "wc", "--connect", endpoint(tmp_path, "router"))
    lead = start("world", *bus, "--agents", 2, "--shard", "1/2", "--out", tmp_path, log=tmp_path / "world1.log")
    try:
        wait_for(lambda: "to join" in (tmp_path / "world1.log").read_text(), 60, "the lead to wait for shard 2")
        lead.send_signal(signal.SIGINT)
        assert finish(lead, 30, tmp_path / "world1.log") == 130
        assert "interrupted (Ctrl-C or SIGTERM): stopped" in (tmp_path / "world1.log").read_text().splitlines()[-1]
        assert not (tmp_path / "metrics.json").exists()
    finally:
        for process in (router, lead):
            process.kill()


def test_a_world_shard_lost_mid_run_ends_the_lead_and_the_brain_with_an_error(tmp_path):
    """kill -9 of world shard 2 mid-run: the lead runs its own slice to the end, then names the lost
    shard and exits 1 (no metrics.json: half the population has no result), not 0. The `--once`
    brain takes the lead's end, names the lost shard too and exits 1; its weights are kept as a run
    that stopped without its end, not saved to --save as a whole run's."""
    with shards_on_a_router(tmp_path, "wl", 1, 20_000) as (worlds, shards):
        # the lead says the run's ticks and seed once every shard has joined
        wait_for(lambda: " ticks, seed " in (tmp_path / "world1.log").read_text(), 120, "the run to start")
        time.sleep(0.5)
        worlds[1].kill()
        assert finish(worlds[0], 120, tmp_path / "world1.log") == 1
        log = (tmp_path / "world1.log").read_text()
        assert "world-2of2 left the bus before the end of its ticks: the run has no result for its insects" in log
        assert not (tmp_path / "metrics.json").exists()
        assert finish(shards[0], 60, tmp_path / "brain1.log") == 1
    log = (tmp_path / "brain1.log").read_text()
    assert "(world-2of2 left the bus before the end of its ticks): its weights so far saved to" in log
    assert "has no whole result (world-2of2 left the bus before the end of its ticks); --once ends here" in log
    assert not (tmp_path / "weights1.npz").exists() and len(list(tmp_path.glob("weights1-*-tick*.npz"))) == 1


def test_a_world_shard_started_again_when_the_run_is_under_way_says_so_and_stays_off(tmp_path):
    """World shard 2 killed mid-run and started again: the lead named the run only until every shard
    had joined, so the new one would wait for a name without end; it says the run is under way and
    ends (exit 2) once the lead has been on the bus naming none for 10 s."""
    with shards_on_a_router(tmp_path, "wu", 1, 10**8) as (worlds, shards):
        wait_for(lambda: " ticks, seed " in (tmp_path / "world1.log").read_text(), 120, "the run to start")
        worlds[1].kill()
        bus = ("--group", "wu", "--connect", endpoint(tmp_path, "router"))
        world = ("--ticks", 10**8, "--seed", SEED, "--agents", AGENTS, "--params", options(tmp_path).params)
        again = start("world", *bus, *world, "--shard", "2/2", "--out", tmp_path, log=tmp_path / "again.log")
        try:
            assert finish(again, 60, tmp_path / "again.log") == 2
        finally:
            again.kill()
    said = (tmp_path / "again.log").read_text()
    assert "world shard 2/2: world shard 1 is on the bus of group wu but has named no run for 10 s: its run is " in said
    assert "under way, every shard joined (a shard cannot join a run under way: start the run again" in said


def test_the_lead_lost_mid_run_ends_the_once_brains_that_served_it(tmp_path):
    """kill -9 of world shard 1: a sharded world keeps no checkpoints, so no run comes back to go
    on; each `--once` brain shard keeps its learning so far once, says so and ends (exit 1), not
    waits, and world shard 2 runs its ticks, then ends with exit 1: no lead ended the run. World
    shard 2 freezes a moment after the lead is lost: a pause of a shard still on the bus is not the
    run's stop, so no brain shard keeps its learning then and again at the end."""
    with shards_on_a_router(tmp_path, "wk", 2, 20_000) as (worlds, shards):
        serving(tmp_path, 2)
        time.sleep(0.5)
        worlds[0].kill()
        time.sleep(0.5)
        worlds[1].send_signal(signal.SIGSTOP)
        time.sleep(1.0)  # four of a brain's quarter-second waits for sensors
        assert " ticks in " not in (tmp_path / "world2.log").read_text()  # frozen mid-run, not at its end
        worlds[1].send_signal(signal.SIGCONT)
        assert finish(worlds[1], 120, tmp_path / "world2.log") == 1
        assert "world shard 1 left the bus before it ended the run" in (tmp_path / "world2.log").read_text()
        for j, brain in enumerate(shards, 1):
            assert finish(brain, 60, tmp_path / f"brain{j}.log") == 1
            log = (tmp_path / f"brain{j}.log").read_text()
            assert "kept no checkpoint of it to resume from and has not come back in 15 s; --once ends here" in log
            assert re.search(r"weights so far saved to \S+weights\d-\w+-tick\d+\.npz", log)
            assert log.count("without its end") == 1 and len(list(tmp_path.glob(f"weights{j}-*-tick*.npz"))) == 1


def test_ctrl_c_at_the_lead_ends_the_run_at_every_brain_shard(tmp_path):
    """Ctrl-C at world shard 1 once world shard 2 is ahead of it (the shards are not in step; here
    the lead froze a moment): the lead's end names its own tick, before the last that brain shards
    2 and 3 answered world shard 2, which stops at its next tick. Every brain shard ends the run with
    that end, its weights saved to --save and exit 0, not kept as a run that stopped without it."""
    with shards_on_a_router(tmp_path, "wc", 3, 200_000) as (worlds, shards):
        serving(tmp_path, 3)
        time.sleep(0.5)
        worlds[0].send_signal(signal.SIGSTOP)
        time.sleep(1.0)  # world shard 2 goes on alone
        worlds[0].send_signal(signal.SIGINT)  # taken as it goes on
        worlds[0].send_signal(signal.SIGCONT)
        for i, process in enumerate(worlds, 1):
            assert finish(process, 60, tmp_path / f"world{i}.log") == 130  # cut short, with a result
        for j, process in enumerate(shards, 1):
            assert finish(process, 30, tmp_path / f"brain{j}.log") == 0
    lead, other = json.loads((tmp_path / "metrics.json").read_text())["shard_ticks"]
    assert other > lead  # world shard 2 was ahead when the lead ended the run
    assert (
        f"world shard 1 ended the run at its tick {lead}: this shard ends it at {other}"
        in (tmp_path / "world2.log").read_text()
    )
    for j in (1, 2, 3):
        log = (tmp_path / f"brain{j}.log").read_text()
        assert f"run ended at tick {lead}" in log and "without its end" not in log
        assert (tmp_path / f"weights{j}.npz").exists()
    assert not list(tmp_path.glob("weights*-tick*.npz"))


def test_ctrl_c_at_a_world_shard_alone_stops_its_ticks_and_it_waits_for_the_leads_end(tmp_path):
    """Ctrl-C at world shard 2 alone: its ticks stop, and it stays on the bus, saying so, while the
    lead runs on; once the lead ends the run (Ctrl-C there too) both end with the run's metrics,
    partial, its ticks the fewest (shard 2's)."""
    with shards_on_a_router(tmp_path, "wa", 2, 200_000) as (worlds, shards):
        serving(tmp_path, 2)
        worlds[1].send_signal(signal.SIGINT)
        log = tmp_path / "world2.log"
        wait_for(lambda: "stays on the bus until world shard 1 ends the run" in log.read_text(), 60, "shard 2 to stay")
        time.sleep(1.0)
        assert worlds[1].poll() is None and worlds[0].poll() is None  # the lead runs on, shard 2 waits for it
        worlds[0].send_signal(signal.SIGINT)
        for i, process in enumerate(worlds, 1):
            assert finish(process, 60, tmp_path / f"world{i}.log") == 130
    merged = json.loads((tmp_path / "metrics.json").read_text())
    lead, other = merged["shard_ticks"]
    assert merged["partial"] and merged["ticks"] == other < lead


def test_every_world_shard_is_recorded_as_one_population(tmp_path):
    """2 world shards publish their slices' state, the recorder makes one recording of the 7 insects:
    every tick's poses are the one-process closed loop's, agent 4 (world shard 2's) the detail agent
    and its arena the map shown; forged shard states (a slice that is not a shard's, one outside the
    population, one of another number of shards) are refused in a line each and the recording goes on."""
    made, router_at = options(tmp_path), endpoint(tmp_path, "router")
    bus = ("--group", "wr", "--connect", router_at)
    router = start("router", "--listen", router_at, log=tmp_path / "router.log")
    recorder = start("record", *bus, "--out", tmp_path / "rec.rrd", "--detail", 4, log=tmp_path / "recorder.log")
    worlds, brains = start_shards(tmp_path, bus, made, 3, "--publish-state")
    forger = Watcher([router_at], [])
    try:
        log1 = tmp_path / "world1.log"
        wait_for(lambda: log1.exists() and re.search(r"run \w+: \d+ ticks", log1.read_text()), 60, "the run")
        run = logged(log1.read_text(), r"run (\w+): \d+ ticks").group(1)
        time.sleep(1)  # the shards' maps and first states are in before the forgeries
        for first, agents, shards in ((4, 3, 2), (5, 3, 2), (4, 3, 3)):
            forger.session.put(keys.world_state("wr"), encode(forged_state(run, first, agents, shards)))
        for i, process in enumerate(worlds, 1):
            assert finish(process, 120, tmp_path / f"world{i}.log") == 0
        for j, process in enumerate(brains, 1):
            assert finish(process, 30, tmp_path / f"brain{j}.log") == 0
        assert finish(recorder, 60, tmp_path / "recorder.log") == 0
    finally:
        forger.close()
        for process in (*worlds, *brains, recorder, router):
            process.kill()
    said = (tmp_path / "recorder.log").read_text()
    assert "(ticks 0..2999)" in said and "ticks missing: none" in said
    for why in (
        "agents 4..6: not one of 2 world shards' slices of 7",
        "agents 5..7 outside the population of 7",
        "world shard of agents 4..6: one of 3 shards of 7 agents; the recording's are 2 of 7",
    ):
        assert len([line for line in said.splitlines() if "WARNING rejected message" in line and why in line]) == 1
    alone = world_from(made)
    start_grid, pos = alone.grid[4].copy(), []
    closed_loop(
        alone,
        brain_for(alone, load_circuit("insect").with_learning_rate(0.04)),
        TICKS,
        lambda t: pos.append(alone.pos.copy()),
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["collisions"] == alone.metrics.collisions.tolist()  # the run recorded is the run
    data = read(tmp_path / "rec.rrd")
    insects = data["/world/insects"]
    assert insects["tick"] == list(range(TICKS))
    p = alone.params
    shown = [np.column_stack([at[:, 0] - p.x_min + 0.5, (p.height - 1) - (at[:, 1] - p.y_min) + 0.5]) for at in pos]
    np.testing.assert_allclose(np.array(insects["Points2D:positions"]), np.array(shown), atol=1e-4)  # float32
    frames = data["/world/map"]["SegmentationImage:buffer"]
    for frame, grid in ((frames[0], start_grid), (frames[-1], alone.grid[4])):  # agent 4's arena, food eaten
        image = np.frombuffer(bytes(frame[0]), np.uint8).reshape(grid.shape[1], grid.shape[0])
        np.testing.assert_array_equal(image, grid[:, ::-1].T)
    assert len(frames) == alone.metrics.food[4] + 1
    assert data["/world/heading/agent4"]["tick"] == list(range(TICKS))


def forged_state(run: str, first: int, agents: int, shards: int) -> WorldState:
    """A state of agents first.. first + agents - 1 of 7, as one of `shards` world shards', for a tick of the run."""
    return WorldState(
        tick=10,
        run=run,
        sensor_names=SENSORS,
        sensors=Array.of(np.zeros((1, agents, len(SENSORS)))),
        pos=Array.of(np.zeros((1, agents, 2))),
        heading=Array.of(np.zeros((1, agents))),
        events=Array.of(np.zeros((1, agents, 4), np.int64)),
        collisions=Array.of(np.zeros((1, agents), np.int64)),
        food=Array.of(np.zeros((1, agents), np.int64)),
        changes=Array.of(np.zeros((0, 5), np.int64)),
        first=first,
        population=AGENTS,
        shards=shards,
    )


def test_the_scale_benchmark_measures_world_shards():
    done = subprocess.run(
        [sys.executable, "-m", "spikinglab", "bench", "scale", "--agents", "40", "--ticks", "100"]
        + ["--shards", "3", "--world-shards", "1", "2"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    assert figures["agents"] == 40 and figures["shards"].keys() == {"3"}
    assert {w: set(rates) for w, rates in figures["world_shards"].items()} == {"1": {"3"}, "2": {"3"}}
    assert all(rate > 0 for rates in figures["world_shards"].values() for rate in rates.values())
    rows = [line.split("|") for line in done.stdout.splitlines() if line.count("|") == 4][1:]
    (_, _, first, _, _), (_, _, second, up, of_linear) = rows  # 1x3, then 2x3
    speed_up = int(second.replace(",", "")) / int(first.replace(",", ""))
    assert abs(float(up) - speed_up) <= 0.01
    assert abs(float(of_linear.split("(")[0]) - speed_up / (5 / 4)) <= 0.01  # over the shards: 2 + 3 of 1 + 3


def test_the_scale_benchmark_refuses_impossible_cases_before_starting():
    for options in (["--agents", "2", "--shards", "3"], ["--agents", "2", "--shards", "1", "--world-shards", "3"]):
        done = subprocess.run(
            [sys.executable, "-m", "spikinglab", "bench", "scale", *options], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 2 and done.stdout == ""
        assert len(done.stderr.splitlines()) == 1 and "at most one shard per agent" in done.stderr


def test_the_lead_merges_no_shard_file_of_another_run_nor_one_half_written(tmp_path, caplog):
    """A folder that holds world shard 2's file of an earlier run (shard 2 of this run had not
    stopped yet): no metrics.json, not one that mixes two runs, and the earlier run's goes too."""
    part = {"run": "now", "agents": 1, "ticks": 10, "partial": False, "rejected_messages": {}}
    (tmp_path / "metrics-1of2.json").write_text(json.dumps(part))
    (tmp_path / "metrics-2of2.json").write_text(json.dumps(part | {"run": "before"}))
    (tmp_path / "metrics.json").write_text("{}")
    merge_metrics(tmp_path, 2, [], "now")
    assert not (tmp_path / "metrics.json").exists()
    assert f"no metrics.json of run now in {tmp_path}: metrics-2of2.json of another run" in caplog.text
    (tmp_path / "metrics-2of2.json").unlink()  # a shard with another --out
    merge_metrics(tmp_path, 2, [], "now")
    assert f"no metrics.json of run now in {tmp_path}: metrics-2of2.json not there" in caplog.text
    (tmp_path / "metrics-2of2.json").write_text(json.dumps(part)[:20])  # caught half written
    merge_metrics(tmp_path, 2, [], "now")
    assert f"{tmp_path}: metrics-2of2.json unreadable (Unterminated string" in caplog.text
