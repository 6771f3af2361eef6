"""`spikinglab bench engine`'s parts run on the engine as it is now (their figures are in docs/results.md)."""

from services.brain.circuit import load_circuit
from spikinglab.bench.engine import call_costs, order_split


def test_call_costs_times_every_part():
    """The no-op given the arrays one by one takes as many as the structures hold (a field added
    to Network or State once broke it)."""
    costs = call_costs(load_circuit("insect"), calls=20, repeats=1)
    assert list(costs)[:3] == ["step", "tick", "no-op, 2 structures"] and len(costs) == 4
    assert all(isinstance(ns, int) and ns > 0 for ns in costs.values())


def test_order_split_reports_each_case_with_the_same_feeds():
    result = order_split(load_circuit("insect"), agents=8, ticks=200, rounds=1)
    spikes = {k: v for k, v in result.items() if k.endswith("_spikes_per_agent_tick")}
    assert len(spikes) == 4 and all(v > 0 for v in spikes.values())
    # the turns by receiver and one by one: the same spikes
    random_order = "netlogo_random_order{}_spikes_per_agent_tick"
    assert spikes[random_order.format("")] == spikes[random_order.format("_turns_one_by_one")]
    assert all(result[k.replace("_spikes_per_agent_tick", "_agent_ticks_per_s")] > 0 for k in spikes)
