"""`spikinglab sweep --netlogo-seed N` and `evaluate(..., netlogo_seed=N)`: every insect in the
SpikingLab source's arena of `random-seed N`, the seeds varying only the netlogo engine's order."""

import numpy as np
import pytest

from services import sweep
from services.loop import closed_loop, evaluate, population
from services.world.netlogo_setup import spikinglab_setup
from services.world.world import params_for


def test_every_insect_has_the_sources_arena_and_heading_and_its_own_order():
    setup = spikinglab_setup(7850, params_for("netlogo"))
    world, brain = population({"a_plus": [0.02, 0.04]}, range(3), preset="netlogo", netlogo_seed=7850)
    assert all(np.array_equal(g, setup.grid) for g in world.grid)
    assert list(world.heading) == [setup.heading] * 6
    closed_loop(world, brain, 600)
    paths = [tuple(p) for p in world.pos[:3]]  # A = 0.02 on seeds 0, 1, 2: one arena, three orders
    assert len(set(paths)) == 3


@pytest.mark.parametrize("semantics, order", [("netlogo", "file"), ("phased", "random")])
def test_without_the_random_order_the_seeds_of_the_sources_arena_are_one_run(semantics, order):
    world, brain = population(
        {"a_plus": [0.02]}, range(3), preset="netlogo", semantics=semantics, order=order, netlogo_seed=7850
    )
    closed_loop(world, brain, 600)
    assert len({tuple(p) for p in world.pos}) == 1  # why the sweep refuses this combination


def test_evaluate_takes_the_sources_arena():
    mine = evaluate({"a_plus": [0.04]}, 1000, seeds=range(2), preset="netlogo", netlogo_seed=7850)
    own = evaluate({"a_plus": [0.04]}, 1000, seeds=range(2), preset="netlogo")
    assert mine["collisions"].tolist() != own["collisions"].tolist()


def test_the_sweep_names_its_arena_in_every_row():
    rows = sweep.sweep([0.02], 2, 1000, "netlogo", 5000, netlogo_seed=7850)
    assert rows[0]["netlogo_seed"] == 7850 and "random-seed 7850" in rows[0]["name"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--order", "file"], "with --semantics netlogo --order file they would be one run copied"),
        (["--semantics", "phased"], "with --semantics phased --order random they would be one run copied"),
        (["--order", "netlogo-stream"], "the seeds would be one run copied: run it alone with spikinglab run"),
    ],
)
def test_a_sweep_whose_seeds_would_be_copies_is_refused_in_one_line(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        sweep.main(["--netlogo-seed", "7850", *argv, "--runs", str(tmp_path)])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not list(tmp_path.iterdir())  # refused before any run or folder


def test_the_stream_order_without_a_netlogo_seed_is_refused_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        sweep.main(["--order", "netlogo-stream", "--runs", str(tmp_path)])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and "--order netlogo-stream draws every insect's order" in line
    assert not list(tmp_path.iterdir())


def test_a_netlogo_seed_outside_netlogos_range_is_refused_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit):
        sweep.main(["--netlogo-seed", str(2**31), "--runs", str(tmp_path)])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "argument --netlogo-seed: must be at most 2,147,483,647 (a Java int), got 2,147,483,648" in line
