"""The netlogo semantics on tiny circuits: when a pulse arrives under each order, a refractory
neuron reopening inside a tick, NetLogo's dt = 0 quirk, and determinism by seed."""

import math

import numpy as np
import pytest

from services.brain.build import BY_RECEIVER_FROM, HIST_LEN, TICK, mix
from services.brain.circuit import build_circuit, load_circuit
from services.brain.engine import PARALLEL_FROM, Engine, order_draw

from .helpers import random_feeds, run_with_events


def chain(order, delay, weight=20):
    """a_in -> A -> B (delay `delay`); the neurons are declared in `order`, the file order."""
    return build_circuit(
        {
            "neurons": {n: "regular" for n in order},
            "inputs": {"a_in": {"target": "A"}},
            "synapses": [{"from": "A", "to": "B", "weight": weight, "delay": delay}],
        }
    )


def converging(a_plus):
    """U and C onto M, delay 1 each: U's pulse (weight 20) makes M fire, C's (weight 5) is plastic,
    learning at `a_plus` (NetLogo's dt = 0 case when both fire at once)."""
    return build_circuit(
        {
            "neurons": {"U": "regular", "M": "regular", "C": "regular"},
            "inputs": {"u_in": {"target": "U"}, "c_in": {"target": "C"}},
            "synapses": [
                {"from": "U", "to": "M", "weight": 20, "delay": 1},
                {"from": "C", "to": "M", "weight": 5, "delay": 1, "plastic": True},
            ],
        }
    ).with_learning_rate(a_plus)


@pytest.mark.parametrize("delay", [1, 2, 3, 5])
def test_a_pulse_arrives_after_d_minus_1_or_d_ticks_by_the_order(delay):
    # A fires at tick 0; its pulse is counted down from d in that tick and delivered at 0, in A's
    # turn of tick d - 1: B fires in that tick if its turn comes after A's, else one tick later.
    for order, expected in ((("A", "B"), delay - 1), (("B", "A"), delay)):
        e = Engine(chain(order, delay), semantics="netlogo", order="file")
        spikes = run_with_events(e, 12, {0: {"a_in": 0}})
        assert spikes["A"] == [0]
        assert spikes["B"] == [expected], order
    # the phased engine: exactly d, whatever the file order
    for order in (("A", "B"), ("B", "A")):
        assert run_with_events(Engine(chain(order, delay), semantics="phased"), 12, {0: {"a_in": 0}})["B"] == [delay]


def test_random_order_gives_both_arrival_ticks_from_the_seed():
    seen = {}
    for seed in range(64):
        e = Engine(chain(("A", "B"), 3), semantics="netlogo", order="random", seed=seed)
        seen[seed] = run_with_events(e, 12, {0: {"a_in": 0}})["B"]
    assert {tuple(b) for b in seen.values()} == {(2,), (3,)}
    assert 16 <= sum(b == [2] for b in seen.values()) <= 48  # about half each way
    again = Engine(chain(("A", "B"), 3), semantics="netlogo", order="random", seed=5)
    assert run_with_events(again, 12, {0: {"a_in": 0}})["B"] == seen[5]  # the seed fixes the order


def fisher_yates(order_key, tick, neurons):
    """The random order of turns as docs/tick.md defines it: Fisher-Yates on order_draw's draws
    from a hash of (agent seed, tick), in plain Python (the kernels draw it packed or by rows)."""
    order, r = list(range(neurons)), mix(np.uint64(order_key) + np.uint64(tick))
    for i in range(neurons - 1, 0, -1):
        r, j = order_draw(np.uint64(r), i)
        order[i], order[int(j)] = order[int(j)], order[i]
    return order


@pytest.mark.parametrize("pairs", [4, 8, 9])  # 8 and 16 neurons: the order packed in a word; 18: by rows
@pytest.mark.parametrize("agents", [3, PARALLEL_FROM + 3])
@pytest.mark.parametrize("delay", [1, 2])  # 1: due in A_k's turn of its tick, the turns one by one; 2: by receiver
def test_every_agent_takes_its_turns_in_its_fisher_yates_order(pairs, agents, delay):
    # A_k fires at tick t and its pulse reaches B_k in A_k's turn at t + delay - 1: B_k fires then
    # when its turn comes after A_k's, else a tick later. So each pair shows one comparison of the order.
    c = build_circuit(
        {
            "neurons": {f"{x}{k}": "regular" for x in "AB" for k in range(pairs)},
            "inputs": {f"in{k}": {"target": f"A{k}"} for k in range(pairs)},
            "synapses": [{"from": f"A{k}", "to": f"B{k}", "weight": 20, "delay": delay} for k in range(pairs)],
        }
    )
    agents = max(agents, BY_RECEIVER_FROM) if delay == 2 else agents
    e = Engine(c, agents=agents, semantics="netlogo", order="random", seed=7)
    a_at = [c.node_names.index(f"A{k}") for k in range(pairs)]
    b_at = [c.node_names.index(f"B{k}") for k in range(pairs)]
    for tick in (0, 5, 1000):  # the same kernel's scratch from tick to tick; the order by tick
        e.reset()
        e.state.clock[TICK] = tick
        e.step(np.zeros((agents, pairs)))
        assert e.spiked[:, a_at].all()
        for _ in range(delay - 1):
            e.step()
        for a in range(agents):
            turn = np.argsort(fisher_yates(e.network.order_key[a], tick + delay - 1, 2 * pairs))  # each neuron's place
            expected = [turn[a_at[k]] < turn[b_at[k]] for k in range(pairs)]
            assert e.spiked[a, b_at].tolist() == expected, (tick, a)


def test_a_refractory_neuron_reopens_in_its_turn_and_takes_later_arrivals():
    # B fires at 0 (period 3): its turns at 1, 2, 3 are refractory, and in its turn at 3 it opens
    # again at -75. C's pulse (weight 20, delay 2, C fired at 2) arrives at 3 in C's turn:
    # after B's turn it lifts B to -55 and B fires at 4; before B's turn it is lost.
    def circuit(order):
        return build_circuit(
            {
                "neurons": {n: "regular" for n in order},
                "inputs": {"b_in": {"target": "B"}, "c_in": {"target": "C"}},
                "synapses": [{"from": "C", "to": "B", "weight": 20, "delay": 2}],
            }
        )

    events = {0: {"b_in": 0.0}, 2: {"c_in": 0.0}}
    taken = run_with_events(Engine(circuit(("B", "C")), semantics="netlogo", order="file"), 10, events)
    lost = run_with_events(Engine(circuit(("C", "B")), semantics="netlogo", order="file"), 10, events)
    assert taken["C"] == lost["C"] == [2]
    assert taken["B"] == [0, 4]
    assert lost["B"] == [0]


def test_an_arrival_just_after_the_post_spike_potentiates_at_every_later_arrival():
    # U and C fire at 0; U's pulse (delay 1, weight 20) makes M fire in its turn at 0, and C's
    # plastic pulse (delay 1) arrives after that turn: dt = 0, a potentiation by A+. NetLogo keeps
    # that arrival in M's history and applies the rule to it again at C's next arrival (tick 10),
    # which itself depresses once: w = 5 + A+ + A+ - A- exp(-10 / tau-).
    a = 0.05
    c = converging(a)
    e = Engine(c, semantics="netlogo", order="file")
    spikes = run_with_events(e, 11, {0: {"u_in": 0, "c_in": 0}, 10: {"c_in": 0}})
    assert spikes["M"] == [0] and spikes["C"] == [0, 10]
    k = c.synapse_index("C", "M")
    assert e.w[0, k] == pytest.approx(5 + a + a - a * math.exp(-10 / 18), abs=1e-12)


def test_history_only_fills_in_training():
    c = load_circuit("insect").with_learning_rate(0.05)
    feeds = random_feeds(3, 2000, 1, len(c.inputs))
    e = Engine(c, training=False, semantics="netlogo")
    e.run(feeds)
    np.testing.assert_array_equal(e.w, e.initial_weights)
    assert (e.state.counters[HIST_LEN] == 0).all()  # no arrival was remembered


@pytest.mark.parametrize("agents", [5, PARALLEL_FROM + 3])  # serial and parallel kernels
def test_netlogo_agents_together_equal_each_alone_with_seed_plus_a(agents):
    c = load_circuit("insect").with_learning_rate(0.05)
    feeds = random_feeds(1, 3000, agents, len(c.inputs))
    together = Engine(c, agents=agents, semantics="netlogo", seed=10)
    spikes = together.run(feeds)
    for a in sorted({0, 1, agents - 1}):
        alone = Engine(c, semantics="netlogo", seed=10 + a)
        np.testing.assert_array_equal(alone.run(feeds[:, a : a + 1]), spikes[:, a : a + 1])
        np.testing.assert_array_equal(alone.w, together.w[a : a + 1])
    other_seed = Engine(c, agents=agents, semantics="netlogo", seed=11)
    assert not np.array_equal(other_seed.run(feeds)[:, 0], spikes[:, 0])  # the order is the seed's


def test_unknown_semantics_or_order_is_refused():
    c = load_circuit("insect")
    with pytest.raises(ValueError, match="semantics must be one of phased, netlogo"):
        Engine(c, semantics="brian")
    with pytest.raises(ValueError, match="order must be one of random, file"):
        Engine(c, semantics="netlogo", order="sorted")


def test_each_rule_switched_off_alone():
    # delay counting: counted down from the next tick, a pulse arrives after d or d + 1 ticks
    for order, expected in ((("A", "B"), 3), (("B", "A"), 4)):
        e = Engine(chain(order, 3), semantics="netlogo", order="file", without=("delay_count",))
        assert run_with_events(e, 12, {0: {"a_in": 0}})["B"] == [expected]
    # reopening: without it the neuron opens at the start of the next tick, and C's pulse is lost
    doc = {
        "neurons": {"B": "regular", "C": "regular"},
        "inputs": {"b_in": {"target": "B"}, "c_in": {"target": "C"}},
        "synapses": [{"from": "C", "to": "B", "weight": 20, "delay": 2}],
    }
    e = Engine(build_circuit(doc), semantics="netlogo", order="file", without=("reopen",))
    assert run_with_events(e, 10, {0: {"b_in": 0}, 2: {"c_in": 0}})["B"] == [0]
    # dt = 0: the arrival potentiates once, at its own arrival
    c = converging(0.05)
    e = Engine(c, semantics="netlogo", order="file", without=("dt0",))
    run_with_events(e, 11, {0: {"u_in": 0, "c_in": 0}, 10: {"c_in": 0}})
    assert e.w[0, c.synapse_index("C", "M")] == pytest.approx(5 + 0.05 - 0.05 * math.exp(-10 / 18), abs=1e-12)
    with pytest.raises(ValueError, match="NetLogo rules are delay_count, reopen, dt0, got dt1$"):
        Engine(c, semantics="netlogo", without=("dt0", "dt1"))
    with pytest.raises(ValueError, match="only the netlogo semantics has NetLogo rules to switch off, got 'phased'"):
        Engine(c, semantics="phased", without=("dt0",))  # phased has no NetLogo rules to switch off


def dense_circuit(seed, neurons=10):
    """Random synapses between `neurons` neurons (self-synapses too), delays 2-4, some inhibitory,
    some plastic, inputs onto half: many pulses reach one neuron in one tick, from turns on both
    sides of its own."""
    rng = np.random.default_rng(seed)
    names = [f"N{k}" for k in range(neurons)]
    synapses = []
    for pre in names:
        for post in names:
            if rng.random() < 0.4:
                kind = rng.integers(3)  # 0 plain, 1 inhibitory, 2 plastic
                weight = float(rng.uniform(4, 12))
                synapses.append(
                    {"from": pre, "to": post, "weight": weight, "delay": int(rng.integers(2, 5))}
                    | ({"inhibitory": True} if kind == 1 else {})
                    | ({"plastic": True} if kind == 2 else {})
                )
    inputs = {f"in{k}": {"target": names[k]} for k in range(0, neurons, 2)}
    return build_circuit({"neurons": dict.fromkeys(names, "regular"), "inputs": inputs, "synapses": synapses})


IDENTITY_CIRCUITS = {
    "insect": lambda: load_circuit("insect"),
    "association": lambda: load_circuit("association"),
    "dense": lambda: dense_circuit(4).with_learning_rate(0.2),
    "delay 1": lambda: converging(0.2),  # one by one, but without delay_count
    "18 neurons": lambda: dense_circuit(5, neurons=18),  # one by one: the places do not fit in a word
}


@pytest.mark.parametrize("circuit", IDENTITY_CIRCUITS)
@pytest.mark.parametrize("agents", [BY_RECEIVER_FROM, PARALLEL_FROM + 3])
def test_turns_by_receiver_equal_the_turns_one_by_one(circuit, agents):
    """The netlogo turns neuron by neuron across agents (the default where no pulse is due in the
    tick it is sent) give every spike, potential and weight of the turns agent by agent in order,
    bit for bit: each order and rule, training switched off and on again."""
    c = IDENTITY_CIRCUITS[circuit]()
    rng = np.random.default_rng(2)
    shape = (900, agents, len(c.inputs))
    feeds = np.where(rng.random(shape) < 0.3, rng.random(shape) * 5, np.nan)
    for order, without in (("random", ()), ("file", ()), ("random", ("delay_count",)), ("random", ("reopen",))):
        engines = [Engine(c, agents, order=order, seed=3, without=without, by_receiver=b) for b in (True, False)]
        for k, feed in enumerate(feeds):
            if k in (500, 600):
                for e in engines:
                    e.training = k == 600
            by_receiver, one_by_one = (e.step(feed).copy() for e in engines)
            assert np.array_equal(by_receiver, one_by_one), (order, without, k)
        by_receiver, one_by_one = engines
        assert np.array_equal(by_receiver.v, one_by_one.v) and np.array_equal(by_receiver.w, one_by_one.w)
        assert np.array_equal(by_receiver.state.hist, one_by_one.state.hist), (order, without)
        assert not np.array_equal(by_receiver.w, by_receiver.initial_weights)  # it learned
