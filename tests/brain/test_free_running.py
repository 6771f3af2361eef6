"""The free-running brain's clock: its lateness statistics take the same memory after any number
of ticks, and their quantiles are those of every tick's lateness, within a bin."""

import sys

import numpy as np
import pytest

from services.brain.free_running import Clock, Lateness


def test_lateness_quantiles_are_those_of_all_ticks_within_half_a_percent():
    rng = np.random.default_rng(1)
    late = np.concatenate([rng.lognormal(np.log(20e-6), 0.5, 50_000), rng.uniform(1e-3, 5e-3, 600)])
    lateness = Lateness()
    for seconds in late:
        lateness.add(float(seconds))
    for q in (0.5, 0.99):
        assert lateness.quantile(q) == pytest.approx(np.quantile(late, q), rel=0.006), q
    assert lateness.max == late.max()
    stats = lateness.stats_ms()
    assert set(stats) == {"late_ms_median", "late_ms_p99", "late_ms_max"}
    assert stats["late_ms_max"] == round(late.max() * 1000, 3)


def test_on_time_ticks_and_no_ticks():
    lateness = Lateness()
    assert lateness.stats_ms() == {"late_ms_median": 0.0, "late_ms_p99": 0.0, "late_ms_max": 0.0}
    for _ in range(99):
        lateness.add(0.0)
    lateness.add(30.0)  # beyond the last bin: counted there, the maximum exact
    assert lateness.quantile(0.5) == 0.0 and lateness.max == 30.0 and lateness.quantile(1.0) == 30.0


def test_the_clock_keeps_the_same_memory_however_many_ticks():
    """At 1 kHz a robot brain ticks 3.6 million times an hour: nothing kept may grow with them."""
    clock = Clock(1e6)  # a tick due every microsecond: the clock never sleeps
    clock.wait()
    sizes = {name: sys.getsizeof(value) for name, value in vars(clock.lateness).items()}
    for _ in range(100_000):
        clock.wait()
    assert clock.lateness.total == 100_001
    assert {name: sys.getsizeof(value) for name, value in vars(clock.lateness).items()} == sizes
    assert all(not isinstance(value, list) for value in vars(clock).values())
