"""A sharded brain: N brain processes each serve a slice of the population, as one brain would."""

import json
import subprocess
import sys

import numba
import numpy as np

from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.loop import brain_for, closed_loop
from services.world.world import SENSORS, World, params_for
from spikinglab.bench.scale import links

from .processes import continued_where_lost, endpoint, finish, kill_mid_run, start, watched_world

TICKS, SEED, AGENTS = 3000, 3, 7  # 7 agents in 3 shards: slices of 2, 2 and 3


def test_three_shards_run_bit_for_bit_as_one_brain(tmp_path):
    """With a parameter file of a row per agent, read whole by world and shards: each shard takes
    its slice of the brain's columns."""
    columns = {
        "a_plus": 0.01 * (1 + np.arange(AGENTS) % 4),
        "a_minus": np.full(AGENTS, 0.04),
        "w_max": 10.0 + np.arange(AGENTS),
        "move_step": 1 - 0.05 * np.arange(AGENTS),
    }
    study = tmp_path / "study.csv"
    np.savetxt(study, np.column_stack(list(columns.values())), delimiter=",", header=",".join(columns), comments="")
    world_ep = endpoint(tmp_path, "world")
    world = start(
        "world",
        "--group",
        "sh",
        "--listen",
        world_ep,
        "--ticks",
        TICKS,
        "--seed",
        SEED,
        "--agents",
        AGENTS,
        "--shards",
        3,
        "--params",
        study,
        "--out",
        tmp_path,
        log=tmp_path / "world.log",
    )
    shards = [
        start(
            "brain",
            "--group",
            "sh",
            "--connect",
            world_ep,
            "--shard",
            f"{i}/3",
            "--once",
            "--params",
            study,
            "--save",
            tmp_path / f"weights{i}.npz",
            log=tmp_path / f"brain{i}.log",
        )
        for i in (1, 2, 3)
    ]
    try:
        assert finish(world, 120, tmp_path / "world.log") == 0
        for i, shard in enumerate(shards, 1):
            assert finish(shard, 30, tmp_path / f"brain{i}.log") == 0
    finally:
        for process in (world, *shards):
            process.kill()
    circuit = load_circuit("insect")
    alone = World(params_for("paper"), agents=AGENTS, seed=SEED, agent_params={"move_step": columns["move_step"]})
    brain = brain_for(alone, circuit, params={k: columns[k] for k in ("a_plus", "a_minus", "w_max")})
    closed_loop(alone, brain, TICKS)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["ticks"] == TICKS and sum(metrics["collisions"]) > 0
    # the first round trip holds the shards' start (networks built): the benchmarks' rate leaves it out
    assert 0 < metrics["first_tick_s"] < metrics["elapsed_s"]
    assert metrics["steady_ticks_per_s"] > metrics["ticks_per_s"]
    assert metrics["collisions"] == alone.metrics.collisions.tolist()
    assert metrics["food"] == alone.metrics.food.tolist()
    assert metrics["distance"] == np.round(alone.metrics.distance, 3).tolist()
    weights = [load_weights(tmp_path / f"weights{i}.npz", circuit) for i in (1, 2, 3)]
    assert [len(w) for w in weights] == [2, 2, 3]
    np.testing.assert_array_equal(np.concatenate(weights), brain.engine.get_weights())  # bit for bit
    for i in (1, 2, 3):
        assert f"shard {i} of 3" in (tmp_path / f"brain{i}.log").read_text()


def test_a_dead_shard_is_named_and_waited_for(tmp_path):
    world, watcher, states = watched_world(
        tmp_path, "sd", "--ticks", 6000, "--agents", 4, "--shards", 2, "--out", tmp_path
    )
    shard = ("--group", "sd", "--connect", endpoint(tmp_path, "world"), "--once")
    first = start("brain", *shard, "--shard", "1/2", log=tmp_path / "brain1.log")
    second = start("brain", *shard, "--shard", "2/2", log=tmp_path / "brain2.log")
    try:
        kill_mid_run(second, states, tmp_path / "world.log", "brain shard 2/2")
        assert first.poll() is None  # the live shard waits with the world
        second = start("brain", *shard, "--shard", "2/2", log=tmp_path / "brain2-again.log")
        assert finish(world, 120, tmp_path / "world.log") == 0
        assert finish(first, 30, tmp_path / "brain1.log") == 0
        assert finish(second, 30, tmp_path / "brain2-again.log") == 0
    finally:
        for process in (world, first, second):
            process.kill()
        watcher.close()
    continued_where_lost(tmp_path / "world.log", "brain shard 2/2", states, 6000)
    assert "brain shard 1/2 lost" not in (tmp_path / "world.log").read_text()
    assert json.loads((tmp_path / "metrics.json").read_text())["ticks"] == 6000


def test_the_scale_and_loop_benchmarks_print_their_figures():
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "spikinglab",
            "bench",
            "scale",
            "--agents",
            "40",
            "--shards",
            "1",
            "2",
            "--ticks",
            "100",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    assert figures["agents"] == 40 and set(figures["shards"]) == {"1", "2"}
    assert all(v > 0 for v in figures["shards"].values())
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "spikinglab",
            "bench",
            "loop",
            *map(
                str,
                (
                    "--ticks",
                    300,
                    "--agents",
                    300,
                    "--batch-ticks",
                    80,
                    "--large-agents",
                    600,
                    "--large-ticks",
                    20,
                    "--repeats",
                    1,
                ),
            ),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    assert set(figures) == {
        "zenoh_roundtrips_per_s",
        "inprocess_ticks_per_s",
        "bus_ticks_per_s",
        "engine_batch300_agent_ticks_per_s",
        "inprocess_batch300_agent_ticks_per_s",
        "bus_batch300_agent_ticks_per_s",
        "inprocess_batch600_agent_ticks_per_s",
        "bus_batch600_agent_ticks_per_s",
        "recording_ticks_per_s",
    }
    assert all(v > 0 for v in figures.values())


def test_the_scale_benchmark_times_each_link_of_the_chain_on_one_thread():
    threads = numba.get_num_threads()
    figures = links(agents=64, ticks=5)
    assert all(figures[f"{link}_ms"] > 0 for link in ("world", "engine", "message"))
    assert figures["message_bytes"] >= 64 * len(SENSORS) * 8  # the values, float64
    assert numba.get_num_threads() == threads  # its threads given back
