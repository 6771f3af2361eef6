"""STDP against the paper's equations: both windows, edges, clipping, history cap, training off."""

import math

import numpy as np
import pytest

from services.brain.circuit import build_circuit

from .helpers import phased, relay_circuit, run_with_events

A = 0.02  # type 1 default A+ = A-


def pairing(dt, **types):
    """One C pulse reaching M at dt ticks relative to M's spike (caused by U); returns the C->M weight."""
    e = phased(relay_circuit(**types))
    f_u = 100
    f_c = f_u + dt  # both relays add 3 ticks, so arrival - spike = f_c - f_u
    events = {f_u: {"u_in": 0.0}}
    events.setdefault(f_c, {})["c_in"] = 0.0
    spikes = run_with_events(e, 300, events)
    assert spikes["M"] == [f_u + 3]
    return e.w[0, e.circuit.synapse_index("C", "M")]


@pytest.mark.parametrize("dt", [0, -1, -3, -11, -30, -50])
def test_potentiation_inside_negative_window(dt):
    assert pairing(dt) == pytest.approx(5 + A * math.exp(dt / 11), rel=1e-12)


@pytest.mark.parametrize("dt", [1, 2, 4, 18, 40, 75])
def test_depression_inside_positive_window(dt):
    assert pairing(dt) == pytest.approx(5 - A * math.exp(-dt / 18), rel=1e-12)


@pytest.mark.parametrize("dt", [-51, -80, 76, 120])
def test_no_change_outside_the_windows(dt):
    assert pairing(dt) == 5.0


def test_pacemaker_type_uses_its_own_window_and_rates():
    # type 2: A 0.09, tau+ 8, tau- 15, window -25 .. +55
    pace = {"base": "pacemaker"}
    for dt, expected in (
        (-25, 5 + 0.09 * math.exp(-25 / 8)),
        (-26, 5.0),
        (55, 5 - 0.09 * math.exp(-55 / 15)),
        (56, 5.0),
    ):
        assert pairing(dt, pm=pace) == pytest.approx(expected, rel=1e-12)


def test_clipping_at_w_max_and_w_min():
    # type with large rates so a few pairings hit the bounds
    fast = {"a_plus": 4.0, "a_minus": 4.0}
    for order, bound in ((-2, 15.0), (+2, 1.0)):
        e = phased(relay_circuit(fast=fast))
        events = {}
        for k in range(6):
            f_u = 100 + 200 * k
            events.setdefault(f_u, {})["u_in"] = 0.0
            events.setdefault(f_u + order, {})["c_in"] = 0.0
        run_with_events(e, 1400, events)
        assert e.w[0, 0] == bound


def test_history_keeps_the_last_30_arrivals():
    # huge window and tau+ so every remembered arrival adds exactly A+; weight 1 keeps M below threshold
    wide = {"a_plus": 0.1, "a_minus": 0.0, "tau_plus": 1e12, "window_neg": -100000}
    doc = {
        "types": {"wide": wide},
        "neurons": {"C": "regular", "U": "regular", "M": "wide"},
        "inputs": {"c_in": {"target": "C", "pulses": 35}, "u_in": {"target": "U"}},
        "synapses": [
            {"from": "C", "to": "M", "weight": 1, "delay": 3, "plastic": True},
            {"from": "U", "to": "M", "weight": 20, "delay": 3},
        ],
    }
    e = phased(build_circuit(doc))
    spikes = run_with_events(e, 250, {0: {"c_in": 3.0}, 200: {"u_in": 0.0}})
    assert len(spikes["C"]) == 35 and spikes["M"] == [203]
    assert e.w[0, 0] == pytest.approx(1 + 30 * 0.1, rel=1e-9)  # 35 would give 4.5


def test_history_is_cleared_when_the_post_neuron_fires():
    # C before U twice, far apart (outside the window of each other): each spike sees only its own arrival
    e = phased(relay_circuit())
    events = {98: {"c_in": 0.0}, 100: {"u_in": 0.0}, 198: {"c_in": 0.0}, 200: {"u_in": 0.0}}
    run_with_events(e, 300, events)
    one = A * math.exp(-2 / 11)
    assert e.w[0, 0] == pytest.approx(5 + 2 * one, rel=1e-12)


def test_depression_is_applied_once_per_pulse_against_the_latest_spike():
    e = phased(relay_circuit())
    # M fires at 103 and 123; C arrives at 128: dt = 5 from the latest spike only
    run_with_events(e, 300, {100: {"u_in": 0.0}, 120: {"u_in": 0.0}, 125: {"c_in": 0.0}})
    assert e.w[0, 0] == pytest.approx(5 - A * math.exp(-5 / 18), rel=1e-12)


def test_training_off_freezes_weights():
    e = phased(relay_circuit(), training=False)
    rng = np.random.default_rng(3)
    feeds = np.where(rng.random((5000, 1, 2)) < 0.05, rng.random((5000, 1, 2)) * 3, np.nan)
    spikes = e.run(feeds)
    assert spikes[:, 0, 2].sum() > 20  # M fired, so STDP would have acted
    np.testing.assert_array_equal(e.w, e.initial_weights)
    e.training = True
    e.run(feeds)
    assert not np.array_equal(e.w, e.initial_weights)


def test_learning_rate_override_reaches_plastic_targets_only():
    from services.brain.circuit import load_circuit

    c = load_circuit("insect").with_learning_rate(0.04)
    rates = {n: (t.a_plus, t.a_minus) for n, t in zip(c.neuron_names, c.neuron_types)}
    assert rates["PAIN"] == rates["REWARD"] == (0.04, 0.04)
    assert rates["H1"] == (0.09, 0.09) and rates["MOVE"] == (0.02, 0.02)
