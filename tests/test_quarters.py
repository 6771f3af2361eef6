"""Collisions in the first and the last quarter of a run: one helper for run, sweep and evaluate,
right for runs of fewer than four bins (a quarter is then one bin, not none or the whole run)."""

import numpy as np

from services.learning import quarter_collisions
from services.loop import evaluate
from services.sweep import sweep


def test_a_quarter_is_a_quarter_of_the_bins_and_at_least_one():
    bins = np.array([[1, 2, 3, 4, 5, 6, 7, 8], [0, 0, 0, 0, 0, 0, 0, 9]])
    first, last = quarter_collisions(bins)
    assert first.tolist() == [3, 0] and last.tolist() == [15, 9]
    first, last = quarter_collisions([[5, 1, 2]])  # 3,000 ticks: the first bin against the last
    assert first.tolist() == [5] and last.tolist() == [2]
    first, last = quarter_collisions(np.zeros((2, 0)))  # stopped within its first bin
    assert first.tolist() == [0, 0] and last.tolist() == [0, 0]


def test_a_short_sweep_compares_its_first_bin_with_its_last():
    (row,) = sweep([0.04], seeds=2, ticks=3000, preset="paper", learned_after=5000)
    per_bin = row["collisions_per_1000_ticks_mean"]  # the mean of the seeds' bins
    assert len(per_bin) == 3 and per_bin[0] > 0  # it collided early on
    assert np.mean(row["collisions_first_quarter"]) == per_bin[0]
    assert np.mean(row["collisions_last_quarter"]) == per_bin[-1]


def test_a_short_evaluation_counts_the_last_bin_as_its_last_quarter():
    out = evaluate({"a_plus": [0.04]}, 2000, seeds=range(2))
    assert out["collisions_last_quarter"].shape == (1, 2)
    assert (out["collisions_last_quarter"] < out["collisions"]).all()  # not the whole run: it collided early on
