"""Input neurons: latency code, pulse count, busy-ignore, as the NetLogo source's input
neurons do (docs/tick.md).

Fed v at tick t, an input neuron counts floor(v) + 1 ticks, the feed's own tick being the first,
so its pulse comes at t + floor(v) and, over its synapse of delay 0, reaches its target then.
"""

import pytest

from services.brain.circuit import build_circuit

from .helpers import phased, run_with_events


def input_engine(pulses=1):
    doc = {"neurons": {"X": "regular"}, "inputs": {"x_in": {"target": "X", "pulses": pulses}}}
    return phased(build_circuit(doc))


@pytest.mark.parametrize("value,count", [(0.0, 1), (0.2, 1), (1.0, 2), (2.7, 3), (3.99, 4), (12.0, 13)])
def test_latency_is_a_count_of_floor_plus_one(value, count):
    spikes = run_with_events(input_engine(), 40, {5: {"x_in": value}})
    assert spikes["x_in"] == [5 + count - 1]  # tick 5 is the first of the count
    assert spikes["X"] == [5 + count - 1]  # delay 0, weight 20: the target fires in that tick


def test_several_pulses_each_after_the_latency():
    spikes = run_with_events(input_engine(pulses=3), 40, {0: {"x_in": 4.5}})
    assert spikes["x_in"] == [4, 9, 14]


def test_feeds_while_busy_are_ignored():
    events = {0: {"x_in": 4.0}, 1: {"x_in": 0.0}, 4: {"x_in": 0.0}, 5: {"x_in": 1.0}}
    spikes = run_with_events(input_engine(), 40, events)
    # busy from 0 through its pulse at 4 (feeds come before the count in a tick); idle at 5
    assert spikes["x_in"] == [4, 6]


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -1.0])
def test_nan_inf_and_negative_feeds_are_ignored(value):
    spikes = run_with_events(input_engine(), 20, {0: {"x_in": value}})
    assert spikes["x_in"] == []
