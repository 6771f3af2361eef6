"""The Python API as docs/api.md shows it, and the example that uses it."""

import subprocess
import sys
from typing import Any

import numpy as np
import pytest

import spikinglab

from .processes import ROOT


def test_every_api_name_loads():
    assert sorted(spikinglab.__all__) == sorted(spikinglab.API)
    assert set(spikinglab.API) <= set(dir(spikinglab))  # what a notebook completes
    for name in spikinglab.__all__:
        assert getattr(spikinglab, name) is not None, name


def train_population(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, ROOT / "examples" / "train_population.py", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_the_example_trains_a_population_for_the_ticks_asked():
    """32,000 ticks: six rows of 5,000, then a last one of 2,000 (it ran 30,000 and said 32,000)."""
    done = train_population("32000")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    rows = [line.split() for line in lines[1:-2]]
    assert [r[0] for r in rows] == ["5,000", "10,000", "15,000", "20,000", "25,000", "30,000", "32,000"]
    collisions = [int(r[1]) for r in rows[:6]]  # the last row's 2,000 ticks are not comparable
    weights = [float(r[2]) for r in rows]
    assert collisions[-1] < collisions[0] / 2  # the population learns
    assert weights == sorted(weights) and weights[-1] > weights[0]  # BLACK->PAIN potentiated
    assert "of 8 insects learned within 32,000 ticks" in lines[-1]


@pytest.mark.parametrize(
    "given, said",
    [
        ("abc", "argument ticks: expected a whole number, got 'abc'"),  # was int()'s traceback
        ("0", "argument ticks: must be at least 1, got 0"),  # ran nothing and reported 0 ticks
        ("5000 2", "unrecognized arguments: 2"),
    ],
)
def test_the_example_refuses_ticks_it_cannot_run_in_one_line(given, said):
    done = train_population(*given.split(), timeout=60)
    assert done.returncode == 2 and done.stderr.splitlines() == [
        f"train_population.py: {said} (see train_population.py --help)"
    ]
    assert done.stdout == ""


def test_the_example_has_a_help():
    done = train_population("--help", timeout=60)
    assert done.returncode == 0 and "ticks to train (default 60,000)" in done.stdout, done.stderr


P = spikinglab.params_for("paper")
WRONG: Any = lambda value: value  # a value of the wrong type, passed as a user might  # noqa: E731
C = spikinglab.load_circuit("insect")
TWO = spikinglab.World(P, agents=2)
# bad input to the API: a call, the error it raises (before any tick runs) and what its message says
BAD_CALLS = [
    (
        "brain for other agents",
        lambda: spikinglab.closed_loop(TWO, spikinglab.brain_for(spikinglab.World(P, 5), C), 10),
        "the world has 2 insect(s), the brain 5",
    ),
    (
        "negative ticks",
        lambda: spikinglab.closed_loop(TWO, spikinglab.brain_for(TWO, C), -5),
        "ticks: a whole number >= 0, got -5",
    ),
    (
        "ticks not whole",
        lambda: spikinglab.closed_loop(TWO, spikinglab.brain_for(TWO, C), WRONG(10.0)),
        "ticks: a whole number >= 0, got 10.0",
    ),
    (
        "on_tick not a function",
        lambda: spikinglab.closed_loop(TWO, spikinglab.brain_for(TWO, C), 5, on_tick=WRONG(3)),
        "on_tick: a function",
    ),
    ("evaluate for 0 ticks", lambda: spikinglab.evaluate({"a_plus": 0.02}, 0), "ticks: a whole number >= 1, got 0"),
    (
        "evaluate of a number, not its name",
        lambda: spikinglab.evaluate(WRONG(0.02), 1000),
        "params: a mapping of per-agent parameter -> values, e.g. {'a_plus': [0.02]}, got 0.02",
    ),
    (
        "seed not whole",
        lambda: spikinglab.evaluate({"a_plus": 0.02}, 1000, seeds=WRONG([1.5])),
        "seeds: insect numbers, whole numbers >= 0",
    ),
    (
        "seeds a count",
        lambda: spikinglab.evaluate({"a_plus": 0.02}, 1000, seeds=WRONG(2)),
        "seeds: insect numbers, e.g. range(4) or [0, 5] (not a count), got 2",
    ),
    (
        "on_block not a function",
        lambda: spikinglab.evaluate({"a_plus": 0.02}, 1000, on_block=WRONG(3)),
        "on_block: a function",
    ),
    (
        "evaluate's option misspelt",
        lambda: spikinglab.evaluate({"a_plus": 0.02}, 1000, **WRONG({"learnd_after": 5})),
        "evaluate: unknown option 'learnd_after' (its options: circuit, preset, learned_after,",
    ),
    ("world of a preset's name", lambda: spikinglab.World(WRONG("paper")), "params: a WorldParams, e.g. params_for"),
    ("circuit of a number", lambda: spikinglab.load_circuit(WRONG(3)), "load_circuit: a circuit's name or file"),
    (
        "learning rate a word",
        lambda: C.with_learning_rate(WRONG("0.02")),
        "A+ must be a finite number >= 0, got '0.02'",
    ),
    ("learning value unknown", lambda: C.with_learning_params(bogus=1), "unknown learning value 'bogus' (known: rest,"),
    (
        "w_max below the initial weights",
        lambda: spikinglab.evaluate({"w_max": [10, 4]}, 1000, [0]),
        "the values of agent 1 (w_max 4) do not fit circuit 'insect': BLACK->PAIN: weight 5.0 out of range [1.0, 4.0]",
    ),
    ("no agents", lambda: spikinglab.World(P, agents=0), "agents: a whole number >= 1"),
    ("seed negative", lambda: spikinglab.World(P, agents=2, seed=-1), "seed: a whole number >= 0"),
    ("training a word", lambda: spikinglab.World(P, training=WRONG("no")), "training and shared: True or False"),
    (
        "grid of unknown colours",
        lambda: spikinglab.World(P, grid=np.full((P.width, P.height), 9, np.uint8)),
        "grid: patch colours are 0..3, it holds [9]",
    ),
    (
        "grid a list of the wrong shape",
        lambda: spikinglab.World(P, grid=WRONG([[0] * P.width] * P.height)),  # a list of the right one is taken
        f"grid shape {(P.height, P.width)} does not match the params' arena {(P.width, P.height)}",
    ),
    ("grid a word", lambda: spikinglab.World(P, grid=WRONG("#####")), "grid shape () does not match"),
    (
        "move step NaN",
        lambda: spikinglab.params_for("paper", move_step=float("nan")),
        "move_step must be a number above 0, got nan",
    ),
    (
        "unknown world parameter",
        lambda: spikinglab.params_for("paper", bogus=1),
        "unknown world parameter(s) bogus",
    ),
    (
        "start outside",
        lambda: spikinglab.params_for("paper", start=(500.0, 500.0)),
        "start must be (x, y) within x 80..120",
    ),
    (
        "initial weight above w_max",
        lambda: spikinglab.brain_for(TWO, C, params={"initial_weight": 100}),
        "weight 100.0 out of range [1.0, 15.0]",
    ),
    (
        "learning value NaN",
        lambda: C.with_learning_params(a_plus=float("nan")),
        "a_plus must be a finite number, got nan",
    ),
    ("window too long", lambda: C.with_learning_params(window_pos=10**9), "the STDP window is at most 100,000 ticks"),
    (
        "per-agent word",
        lambda: spikinglab.brain_for(TWO, C, params={"a_plus": "big"}),
        "per-agent parameter a_plus: numbers, got 'big'",
    ),
]


@pytest.mark.parametrize("case, call, says", BAD_CALLS, ids=[c[0] for c in BAD_CALLS])
def test_bad_input_to_the_api_is_refused_naming_it(case, call, says):
    with pytest.raises((ValueError, TypeError)) as refused:
        call()
    assert says in str(refused.value)
    assert TWO.tick == 0  # no tick ran
