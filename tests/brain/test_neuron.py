"""The integrate-and-fire state machine against its analytic values (the paper's neuron model; the
NetLogo source's neuron types 1 and 2: docs/circuits.md, docs/tick.md)."""

import numpy as np
import pytest

from services.brain.circuit import build_circuit

from .helpers import phased, run_with_events


def first_feed(engine, **values):
    """A feed for tick 0 with {input name: value}."""
    feed = engine.no_feed.copy()
    for name, value in values.items():
        feed[0, engine.circuit.input_index(name)] = value
    return feed


def one_input(weight, delay=0, inhibitory_weight=None, ntype="regular"):
    doc = {
        "neurons": {"X": ntype},
        "inputs": {"x_in": {"target": "X", "weight": weight, "delay": delay}},
    }
    if inhibitory_weight is not None:
        doc["neurons"]["I"] = "regular"
        doc["inputs"]["i_in"] = {"target": "I"}
        doc["synapses"] = [{"from": "I", "to": "X", "weight": inhibitory_weight, "delay": 1, "inhibitory": True}]
    return phased(build_circuit(doc))


def test_decay_curve_toward_rest():
    e = one_input(weight=8.0)
    trace = []
    for t in range(30):
        e.step(first_feed(e, x_in=0.0) if t == 0 else None)  # the input's pulse arrives at tick 0
        trace.append(e.v[0, 0])
    # the arrival adds 8, then each tick (that one included) removes 8 % of the distance to rest
    k = np.arange(30)
    expected = -65.0 + 8.0 * 0.92 ** (k + 1)
    np.testing.assert_allclose(trace, expected, rtol=0, atol=1e-12)


def test_decay_from_below_rest_never_overshoots():
    e = one_input(weight=1.0, inhibitory_weight=6.0)
    run_with_events(e, 2, {0: {"i_in": 0.0}})  # I fires at 0, its pulse reaches X at 1
    assert e.v[0, 0] == pytest.approx(-65.0 - 6.0 * 0.92)
    for _ in range(500):
        e.step()
        assert e.v[0, 0] <= -65.0
    assert e.v[0, 0] == pytest.approx(-65.0, abs=1e-12)


@pytest.mark.parametrize("weight,fires", [(10.0, True), (9.999, False)])
def test_threshold_crossing(weight, fires):
    e = one_input(weight=weight)
    spikes = run_with_events(e, 10, {0: {"x_in": 0.0}})
    assert spikes["X"] == ([0] if fires else [])  # fires in the tick the input's pulse arrives


@pytest.mark.parametrize("ntype,period,refr_v", [("regular", 3, -75.0), ("pacemaker", 1, -70.0)])
def test_refractory_clamp_and_length(ntype, period, refr_v):
    e = one_input(weight=20.0, ntype=ntype)
    v = []
    for t in range(1 + period):
        e.step(first_feed(e, x_in=0.0) if t == 0 else None)  # X fires at tick 0
        v.append(e.v[0, 0])
    # clamped from the firing tick through the end of the refractory period
    assert v == [refr_v] * (period + 1)
    # a strong pulse in the last refractory tick is ignored; one tick later, it fires
    for arrive, fires in ((period, False), (period + 1, True)):
        e = one_input(weight=20.0, ntype=ntype)
        spikes = run_with_events(e, 20, {0: {"x_in": 0.0}, arrive: {"x_in": 0.0}})
        assert (arrive in spikes["X"]) == fires, (arrive, spikes["X"])


def test_inhibition_floor():
    e = one_input(weight=1.0, inhibitory_weight=50.0)
    run_with_events(e, 2, {0: {"i_in": 0.0}})  # I fires at 0, its pulse reaches X at 1
    # inhibition arrives at tick 1 and is floored at -75; the decay of tick 1 then applies
    assert e.v[0, 0] == pytest.approx(-75.0 + 10.0 * 0.08)


@pytest.mark.parametrize("delay", [1, 2, 3, 5, 8])
def test_arrival_tick_for_each_delay(delay):
    doc = {
        "neurons": {"A": "regular", "B": "regular"},
        "inputs": {"a_in": {"target": "A"}},
        "synapses": [{"from": "A", "to": "B", "weight": 20, "delay": delay}],
    }
    e = phased(build_circuit(doc))
    spikes = run_with_events(e, 20, {0: {"a_in": 0.0}})
    assert spikes["A"] == [0]
    assert spikes["B"] == [delay]  # fires in the tick the pulse arrives


def test_pacemaker_oscillates_and_drives_reward():
    from services.brain.circuit import load_circuit

    e = phased(load_circuit("insect"))
    spikes = run_with_events(e, 300, {})
    assert spikes["kick"] == [1]  # fed 1 at tick 0: floor(1) ticks later
    assert spikes["H1"][:3] == [1, 6, 11]  # H1 -> H2 delay 2, H2 -> H1 delay 3: period 5
    assert spikes["H2"][:3] == [3, 8, 13]
    # H1 -> REWARD (3.5 every 5 ticks) alone lifts REWARD to threshold: the insect keeps moving
    assert len(spikes["REWARD"]) > 0 and len(spikes["MOVE"]) == len(spikes["REWARD"])
    assert spikes["PAIN"] == [] and spikes["ROTATE"] == []
