"""The brain service's lock-step answers, without the bus (BrainNode.answer)."""

import time

import numpy as np
import pytest

from services.brain.brain import Brain
from services.brain.circuit import load_circuit
from services.brain.engine import Engine
from services.brain.node import BrainNode
from services.bus.schemas import Array, BusError, Control, Motor, Sensors
from services.vocabulary import INSECT_ACTIONS, INSECT_SENSORS

AGENTS = 3
CIRCUIT = load_circuit("insect")


def sensors(tick, agents=AGENTS, names=INSECT_SENSORS, seed=5, run="r1", first=0) -> Sensors:
    values = np.full((agents, len(names)), np.nan)
    values[:, 0] = 1.0 + (tick % 4)  # a wall ahead, at a distance that changes
    return Sensors(tick=tick, names=names, values=Array.of(values), seed=seed, run=run, first=first)


def answered(node: BrainNode, message: Sensors) -> Motor:
    """The node's answer, where the test expects one."""
    answer = node.answer(message)
    assert answer is not None, f"no answer to tick {message.tick}"
    return answer


def engine(node: BrainNode) -> Engine:
    assert node.brain is not None, "no brain yet"
    return node.brain.engine


def actions(answer) -> np.ndarray:
    return answer.actions.numpy("actions", "|u1", 2).copy()


def test_answers_as_the_in_process_brain_with_the_worlds_seed():
    node = BrainNode(CIRCUIT)
    direct = Brain(CIRCUIT, INSECT_SENSORS, tuple(CIRCUIT.actuators), agents=AGENTS, seed=5)
    fired = 0
    for t in range(300):
        answer = answered(node, sensors(t))
        assert answer.tick == t and answer.names == INSECT_ACTIONS and node.stepped
        expected = direct.step(sensors(t).values.numpy("values", "<f8", 2))
        np.testing.assert_array_equal(actions(answer), expected)
        fired += int(expected.sum())
    assert fired > 0  # the pacemaker walks: the comparison saw spikes
    np.testing.assert_array_equal(engine(node).get_weights(), direct.engine.get_weights())


def test_a_repeated_tick_is_answered_again_without_a_second_step():
    node = BrainNode(CIRCUIT)
    for t in range(20):
        first = node.answer(sensors(t))
    v = engine(node).v.copy()
    again = node.answer(sensors(19))
    assert again is first and not node.stepped
    np.testing.assert_array_equal(engine(node).v, v)


def test_older_ticks_are_ignored_and_what_does_not_fit_is_refused():
    node = BrainNode(CIRCUIT)
    for t in range(10):
        node.answer(sensors(t))
    assert node.answer(sensors(5)) is None  # older than the last answered: the world moved on
    for other, reason in (
        (sensors(10, agents=2), "does not fit the run: 2 agents"),
        (sensors(10, names=INSECT_SENSORS[::-1]), "does not fit the run"),
        (sensors(10, run="r2"), "another run: sensors of run 'r2' at tick 10"),
    ):
        with pytest.raises(BusError, match=reason):
            node.answer(other)
    assert node.last_tick == 9
    assert answered(node, sensors(10)).tick == 10


def test_a_first_message_the_circuit_cannot_use_is_refused():
    node = BrainNode(CIRCUIT)
    with pytest.raises(BusError, match="does not fit the circuit"):
        node.answer(sensors(0, names=("smell_black", "pain")))
    assert node.brain is None and answered(node, sensors(0)).tick == 0


def test_loaded_weights_of_other_agents_refuse_the_run_and_one_agents_go_to_every_agent():
    """--load weights of 2 agents cannot start a world of 3 (refused like any message that does not
    fit, the brain waiting on); weights of one agent are given to each of the 3."""
    synapses = len(CIRCUIT.synapses)
    node = BrainNode(CIRCUIT, weights=np.full((2, synapses), 7.0))
    with pytest.raises(BusError, match="does not fit the --load weights: they hold 2 agents, the world sends 3"):
        node.answer(sensors(0))
    assert node.brain is None
    assert answered(BrainNode(CIRCUIT, weights=np.full((2, synapses), 7.0)), sensors(0, agents=2)).tick == 0
    one = BrainNode(CIRCUIT, weights=np.full((1, synapses), 7.0), training=False)
    answered(one, sensors(0))
    np.testing.assert_array_equal(engine(one).get_weights(), np.full((AGENTS, synapses), 7.0))


def test_only_an_end_of_the_run_served_ends_it():
    node = BrainNode(CIRCUIT)
    for t in range(10):
        node.answer(sensors(t))
    for order in (Control(tick=10, command="end", run="r2"), Control(tick=3, command="end", run="r1")):
        with pytest.raises(BusError, match="does not fit the run"):
            node.ends(order)  # another run's, or one from before the brain's last tick
    assert node.ends(Control(tick=10, command="end", run="r1"))


def test_an_end_before_any_piece_says_that_no_world_has_sent_this_brain_one():
    """brain --shard 3/3 beside a world of --shards 2 hears the run's end, never a piece of it."""
    with pytest.raises(BusError, match=r"this brain has served no piece of a run yet \(a world of --shards N"):
        BrainNode(CIRCUIT).ends(Control(tick=10, command="end", run="r1"))


def test_a_piece_of_a_sharded_world_takes_its_runs_end_at_the_lead_shards_tick():
    """The lead world shard's end names its own tick; the shard that sends a piece from another
    agent than 0, not in step with the lead, may be past it. Another run's end is still refused, and
    so is one before the last tick of the piece from agent 0, which the lead itself sends."""
    lead, other = BrainNode(CIRCUIT, world_shards=2), BrainNode(CIRCUIT, world_shards=2)
    for t in range(10):
        lead.answer(sensors(t))
        other.answer(sensors(t, first=AGENTS))
    for node in (lead, other):
        with pytest.raises(BusError, match="does not fit the run"):
            node.ends(Control(tick=10, command="end", run="r2"))
    assert other.ends(Control(tick=3, command="end", run="r1"))
    with pytest.raises(BusError, match="does not fit the run"):
        lead.ends(Control(tick=3, command="end", run="r1"))
    assert lead.ends(Control(tick=10, command="end", run="r1"))


def test_tick_zero_of_another_run_is_a_new_run_once_the_run_served_is_quiet():
    node = BrainNode(CIRCUIT, quiet_s=0.3)
    fresh = [actions(answered(node, sensors(t))) for t in range(200)]
    learned = engine(node).get_weights().copy()
    assert node.answer(sensors(0)) is None  # tick 0 of the same run again: older, not a new run
    with pytest.raises(BusError, match="another run"):  # the run served is alive: no take-over
        node.answer(sensors(0, run="r2"))
    np.testing.assert_array_equal(engine(node).get_weights(), learned)
    time.sleep(0.4)
    again = [actions(answered(node, sensors(t, run="r2"))) for t in range(200)]
    assert not np.array_equal(learned, initial_weights())  # the first run changed the weights
    np.testing.assert_array_equal(engine(node).get_weights(), learned)  # and the second, from scratch, the same
    for a, b in zip(fresh, again):
        np.testing.assert_array_equal(a, b)


def initial_weights():
    return Brain(CIRCUIT, INSECT_SENSORS, tuple(CIRCUIT.actuators), agents=AGENTS).engine.get_weights()


def test_sensors_and_actions_are_bound_by_name_in_any_order():
    """The world's columns in another order, and an action the circuit does not drive, give the
    same spikes; a reading of another shape is refused before the compiled binding reads it."""
    feeds = [sensors(t).values.numpy("values", "<f8", 2) for t in range(300)]
    order = [4, 2, 0, 3, 1]
    plain = Brain(CIRCUIT, INSECT_SENSORS, INSECT_ACTIONS, agents=AGENTS, seed=5)
    shuffled = Brain(
        CIRCUIT, tuple(INSECT_SENSORS[k] for k in order), ("jump",) + INSECT_ACTIONS[::-1], agents=AGENTS, seed=5
    )
    fired = 0
    for feed in feeds:
        expected = plain.step(feed)
        got = shuffled.step(np.ascontiguousarray(feed[:, order]))
        np.testing.assert_array_equal(got, np.c_[np.zeros(AGENTS, np.uint8), expected[:, ::-1]])
        fired += int(expected.sum())
    assert fired > 0
    with pytest.raises(ValueError, match=r"sensors of shape \(1, 5\), expected \(3, 5\)"):
        plain.step(feeds[0][:1])
