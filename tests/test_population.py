"""Per-agent parameters: one population of many settings runs each insect as it would run alone."""

import dataclasses
import re
import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from services.brain.circuit import load_circuit
from services.loop import brain_for, closed_loop, evaluate
from services.params import AGENT_PARAMS, PARALLEL_FROM, grid, read_params
from services.world.world import World, params_for

from .processes import ROOT

TICKS = 6000  # the insects collide and learn within it: weights and paths diverge between settings


def run_alone(
    ticks,
    a_plus=0.02,
    w_max=15.0,
    tau_plus=11.0,
    initial_weight=None,
    input_gain=1.0,
    rotation=5.0,
    move=1.0,
    numbers=(0, 1),
    python_loop=False,
):
    """The old way: one population per setting, the setting in the circuit and the world's params."""
    circuit = load_circuit("insect").with_learning_params(a_plus=a_plus, a_minus=a_plus, w_max=w_max, tau_plus=tau_plus)
    n_net = len(circuit.synapses) - len(circuit.inputs)
    sensed = {n_net + k for k in circuit.sensors.values()}  # not the pacemaker's kick
    circuit = dataclasses.replace(
        circuit,
        synapses=tuple(
            dataclasses.replace(s, weight=initial_weight)
            if s.plastic and initial_weight is not None
            else dataclasses.replace(s, weight=s.weight * input_gain)
            if k in sensed
            else s
            for k, s in enumerate(circuit.synapses)
        ),
    )
    world = World(params_for("paper", rotation_step=rotation, move_step=move), agents=2, seed=0, numbers=numbers)
    brain = brain_for(world, circuit)
    closed_loop(world, brain, ticks, (lambda t: None) if python_loop else None)
    return world, brain


SETTINGS: list[dict[str, Any]] = [  # each row: one setting a study might vary; the population holds them all
    dict(a_plus=0.02),
    dict(a_plus=0.04),
    dict(w_max=5.5),
    dict(tau_plus=20.0),
    dict(initial_weight=3.0),
    dict(input_gain=0.6),
    dict(rotation=8.0),
    dict(move=0.6),
]
COLUMN = {"rotation": "rotation_step", "move": "move_step"}


def test_a_population_of_settings_runs_each_insect_as_it_runs_alone():
    names = sorted({k for s in SETTINGS for k in s})
    defaults = dict(
        a_plus=0.02, w_max=15.0, tau_plus=11.0, initial_weight=np.nan, input_gain=1.0, rotation=5.0, move=1.0
    )
    rows = [{**defaults, **s} for s in SETTINGS]
    columns = {COLUMN.get(k, k): np.repeat([r[k] for r in rows], 2) for k in names}
    columns["a_minus"] = columns["a_plus"]
    world_cols = {k: columns.pop(k) for k in ("rotation_step", "move_step")}
    circuit = load_circuit("insect")
    plastic = circuit.plastic_synapses
    # an agent without an initial weight of its own keeps the circuit's: its first plastic weight
    columns["initial_weight"] = np.where(
        np.isnan(columns["initial_weight"]), circuit.synapses[plastic[0]].weight, columns["initial_weight"]
    )
    assert len({circuit.synapses[k].weight for k in plastic}) == 1  # so that holds for every plastic synapse
    world = World(
        params_for("paper"), agents=2 * len(rows), seed=0, numbers=np.tile([0, 1], len(rows)), agent_params=world_cols
    )
    brain = brain_for(world, circuit, params=columns)
    closed_loop(world, brain, TICKS)
    finals = brain.engine.get_weights().reshape(len(rows), 2, -1)
    assert len({finals[k].tobytes() for k in range(len(rows))}) == len(rows)  # every setting made a difference
    for k, setting in enumerate(SETTINGS):
        alone_world, alone_brain = run_alone(TICKS, **setting)
        mine = slice(2 * k, 2 * k + 2)
        np.testing.assert_array_equal(finals[k], alone_brain.engine.get_weights(), err_msg=str(setting))
        np.testing.assert_array_equal(world.pos[mine], alone_world.pos, err_msg=str(setting))
        np.testing.assert_array_equal(world.metrics.collisions[mine], alone_world.metrics.collisions)
        np.testing.assert_array_equal(np.array(world.metrics.bins)[:, mine], np.array(alone_world.metrics.bins))


@pytest.mark.parametrize("semantics", ["netlogo", "phased"])
def test_the_fused_loop_is_the_tick_by_tick_loop(semantics):
    """closed_loop runs stretches of ticks as one compiled call; a per-tick callback steps in Python."""
    runs = []
    for callback in (None, lambda t: None):
        world = World(params_for("paper"), agents=3, seed=4)
        brain = brain_for(world, load_circuit("insect").with_learning_rate(0.04), semantics=semantics)
        closed_loop(world, brain, 1500, callback)
        closed_loop(world, brain, 2700, callback)  # stretches that end between bins, then go on
        runs.append((world, brain))
    (fused, fused_brain), (stepped, stepped_brain) = runs
    assert fused.tick == stepped.tick == 4200 and fused_brain.engine.tick == 4200
    assert fused.metrics.collisions.sum() > 0
    np.testing.assert_array_equal(fused_brain.engine.get_weights(), stepped_brain.engine.get_weights())
    np.testing.assert_array_equal(fused.pos, stepped.pos)
    np.testing.assert_array_equal(fused.grid, stepped.grid)  # food eaten
    for f in dataclasses.fields(fused.metrics):
        np.testing.assert_array_equal(
            np.array(getattr(fused.metrics, f.name)), np.array(getattr(stepped.metrics, f.name)), err_msg=f.name
        )
    np.testing.assert_array_equal(fused_brain.actions, stepped_brain.actions)


def test_evaluate_gives_metrics_per_setting_and_seed_as_the_insects_alone():
    settings = grid(a_plus=[0.02, 0.04], move_step=[1.0, 0.6])
    settings["a_minus"] = settings["a_plus"]
    result = evaluate(settings, TICKS, seeds=[0, 1])
    assert set(result) == {"learning_time", "collisions", "food", "collisions_last_quarter"}
    assert all(v.shape == (4, 2) for v in result.values())
    for k, (a, move) in enumerate(zip(settings["a_plus"], settings["move_step"])):
        alone, _ = run_alone(TICKS, a_plus=a, move=move, python_loop=True)
        np.testing.assert_array_equal(result["collisions"][k], alone.metrics.collisions)
        np.testing.assert_array_equal(result["food"][k], alone.metrics.food)
        np.testing.assert_array_equal(result["learning_time"][k], alone.metrics.learned_at)
        last = np.array(alone.metrics.bins)[-(TICKS // 1000 // 4 or 1) :].sum(axis=0)
        np.testing.assert_array_equal(result["collisions_last_quarter"][k], last)


@pytest.mark.parametrize(
    "params, problem",
    [
        ({"a_plsu": 0.02}, "unknown per-agent parameter"),
        ({"w_max": [10.0, 12.0, 14.0]}, "w_max: (3,) values for 2 agents"),
        ({"tau_plus": [11.0, 0.0]}, "tau_plus: agent 1 has 0.0, it must be a finite number > 0"),
        ({"a_plus": [0.02, np.nan]}, "a_plus: agent 1 has nan"),
        ({"w_max": [15.0, 4.0]}, "out of range [1.0, 4.0]"),  # below the circuit's initial plastic weights
        ({"move_step": 0.5}, "per-agent parameter move_step is the world's, not the brain's"),
    ],
)
def test_a_wrong_column_is_refused_naming_it(params, problem):
    world = World(agents=2)
    with pytest.raises(
        ValueError, match=problem.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]")
    ):
        brain_for(world, load_circuit("insect"), params=params)


def test_a_params_file_a_spreadsheet_saved_with_a_byte_order_mark_is_read(tmp_path):
    path = tmp_path / "params.csv"
    path.write_bytes("a_plus,w_max\n0.02,15\n".encode("utf-8-sig"))
    columns = read_params(path)
    assert list(columns) == ["a_plus", "w_max"]  # not '\ufeffa_plus', an unknown parameter
    np.testing.assert_array_equal(columns["a_plus"], [0.02])


def test_every_column_is_documented():
    text = (ROOT / "docs" / "api.md").read_text()
    for name in AGENT_PARAMS:
        assert f"`{name}`" in text, name


def test_the_optimiser_example_runs_and_prints_the_best():
    done = subprocess.run(
        [
            sys.executable,
            ROOT / "examples" / "optimise.py",
            "--generations",
            "2",
            "--ticks",
            "3000",
            "--seeds",
            "2",
            "--population",
            "4",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert sum(line.startswith("generation") for line in lines) == 2
    best = [line for line in lines if line.startswith("best:")]
    assert len(best) == 1, done.stdout
    found = re.fullmatch(r"best: A\+ = A- = ([0-9.]+), w_max = ([0-9.]+), cost [0-9,]+, learning times .*", best[0])
    assert found, best[0]
    assert 0.005 <= float(found[1]) <= 0.08 and 5 <= float(found[2]) <= 30  # inside the search space


def test_a_large_population_on_every_core_runs_its_insects_as_a_small_one():
    """From PARALLEL_FROM agents on, engine and world kernels run across cores: the same ticks."""
    runs = []
    for agents in (PARALLEL_FROM + 44, 3):
        world = World(params_for("paper"), agents=agents, seed=2)
        brain = brain_for(world, load_circuit("insect").with_learning_rate(0.04))
        closed_loop(world, brain, 3000)
        runs.append((world, brain))
    (large, large_brain), (small, small_brain) = runs
    assert large.world_kernels_parallel and not small.world_kernels_parallel
    np.testing.assert_array_equal(large.pos[:3], small.pos)
    np.testing.assert_array_equal(large.metrics.collisions[:3], small.metrics.collisions)
    np.testing.assert_array_equal(large.grid[:3], small.grid)
    np.testing.assert_array_equal(large_brain.engine.get_weights()[:3], small_brain.engine.get_weights())


@pytest.mark.parametrize(
    "option, said",
    [
        ("--generations 0", "argument --generations: must be at least 1, got 0"),  # printed a best of nothing
        ("--population 1", "argument --population: must be at least 2, got 1"),  # CMA-ES's traceback
        ("--seeds 0", "argument --seeds: must be at least 1, got 0"),
        ("--ticks 500", "argument --ticks: must be at least 1,000, got 500"),
    ],
)
def test_the_optimiser_example_refuses_a_search_it_cannot_run_in_one_line(option, said):
    done = subprocess.run(
        [sys.executable, ROOT / "examples" / "optimise.py", *option.split()],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and done.stderr.strip().splitlines()[-1] == f"optimise.py: error: {said}"
    assert "Traceback" not in done.stderr
