"""Learning time from noxious ticks: the post-hoc definitions agree with the world's own counter."""

import numpy as np
import pytest

from services.brain.circuit import load_circuit
from services.learning import learning_time, noxious_ticks, stats
from services.loop import brain_for, closed_loop
from services.world.world import PAIN, World, params_for


def test_definitions_on_hand_made_ticks():
    assert learning_time([], 100, 50) == 0  # never on a noxious patch
    assert learning_time([3, 10, 70], 100, 50) == 10  # 11..69 is 59 free ticks
    assert learning_time([3, 10, 40, 70], 100, 50) is None  # no gap of 50, and 71..99 is 29
    assert learning_time([3, 10, 40, 70], 121, 50) == 70  # 71..120: 50 free ticks at the end
    # at most one: after 10, ticks 11..44 hold 40 but end at 45 (34 ticks); after 45, 46..99 hold 70
    assert learning_time([3, 10, 40, 45, 70], 100, 50, allowed=1) == 45
    assert learning_time([3, 10, 40, 70], 100, 50, allowed=1) == 10  # 11..69 holds only 40


@pytest.mark.parametrize(
    "ticks_of_one, window, allowed, named",
    [
        ([70, 10], 50, 0, "sorted"),  # unsorted ticks used to read as a gap
        ([3, 200], 50, 0, "sorted ticks in 0..100"),
        ([3.5], 50, 0, "whole ticks"),
        ([3], 0, 0, "window must be >= 1"),
        ([3], 50, -1, "allowed >= 0"),
    ],
)
def test_a_learning_time_of_ticks_that_cannot_be_a_runs_is_refused(ticks_of_one, window, allowed, named):
    with pytest.raises(ValueError, match=named):
        learning_time(ticks_of_one, 100, window, allowed)


def test_censored_statistics():
    s = stats([100, None, 300, None, 200], ticks=1000)
    assert s["median"] == 300 and s["reached"] == 3 and s["q3"] is None


def test_post_hoc_definition_equals_the_worlds_counter_on_a_real_run():
    ticks, window = 12_000, 1_000
    world = World(params_for("paper", learned_after=window), agents=6, seed=0)
    brain = brain_for(world, load_circuit("insect").with_learning_rate(0.04), semantics="netlogo")
    noxious = noxious_ticks(world, brain, ticks)
    expected = [None if t < 0 else int(t) for t in world.metrics.learned_at]
    assert [learning_time(n, ticks, window) for n in noxious] == expected
    assert any(t is not None for t in expected) and all(len(n) > 0 for n in noxious)


def test_the_compiled_loop_keeps_the_same_noxious_ticks_as_reading_the_pain_sensor_each_tick():
    """noxious_ticks runs stretches of ticks as one compiled call that keeps the ticks the pain
    sensor was fed; reading the sensor after every tick in Python gives the same, and on_tick
    sees every tick."""
    runs, seen = [], []
    for compiled in (True, False):
        world = World(params_for("paper"), agents=3, seed=2)
        brain = brain_for(world, load_circuit("insect").with_learning_rate(0.04), semantics="netlogo")
        if compiled:
            runs.append(noxious_ticks(world, brain, 2500, seen.append))
            continue
        kept = [[] for _ in range(world.agents)]

        def keep(t, world=world, kept=kept):
            for agent in np.flatnonzero(~np.isnan(world.sensors[:, PAIN])):
                kept[agent].append(t)

        closed_loop(world, brain, 2500, keep)
        runs.append(kept)
    assert runs[0] == runs[1] and all(runs[0])
    assert seen == list(range(2500))
