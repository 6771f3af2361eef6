"""The brain service's lock-step answers, without the bus (BrainNode.answer)."""

import numpy as np

from spikinglab.brain.brain import Brain
from spikinglab.brain.circuit import load_circuit
from spikinglab.brain.service import BrainNode
from spikinglab.bus.schemas import INSECT_ACTIONS, INSECT_SENSORS, Array, Sensors

AGENTS = 3
CIRCUIT = load_circuit("insect")


def sensors(tick, agents=AGENTS, names=INSECT_SENSORS, seed=5) -> Sensors:
    values = np.full((agents, len(names)), np.nan)
    values[:, 0] = 1.0 + (tick % 4)  # a wall ahead, at a distance that changes
    return Sensors(tick=tick, names=names, values=Array.of(values), seed=seed)


def actions(answer) -> np.ndarray:
    return answer.actions.numpy("actions", "|u1", 2).copy()


def test_answers_as_the_in_process_brain_with_the_worlds_seed():
    node = BrainNode(CIRCUIT)
    direct = Brain(CIRCUIT, INSECT_SENSORS, tuple(CIRCUIT.actuators), agents=AGENTS, seed=5)
    fired = 0
    for t in range(300):
        answer = node.answer(sensors(t))
        assert answer.tick == t and answer.names == INSECT_ACTIONS and node.stepped
        expected = direct.step(sensors(t).values.numpy("values", "<f8", 2))
        np.testing.assert_array_equal(actions(answer), expected)
        fired += int(expected.sum())
    assert fired > 0  # the pacemaker walks: the comparison saw spikes
    np.testing.assert_array_equal(node.brain.engine.get_weights(), direct.engine.get_weights())


def test_a_repeated_tick_is_answered_again_without_a_second_step():
    node = BrainNode(CIRCUIT)
    for t in range(20):
        first = node.answer(sensors(t))
    v = node.brain.engine.v.copy()
    again = node.answer(sensors(19))
    assert again is first and not node.stepped
    np.testing.assert_array_equal(node.brain.engine.v, v)


def test_older_ticks_and_wrong_shapes_are_ignored():
    node = BrainNode(CIRCUIT)
    for t in range(10):
        node.answer(sensors(t))
    assert node.answer(sensors(5)) is None  # older than the last answered
    assert node.answer(sensors(10, agents=2)) is None  # not this brain's agents
    assert node.answer(sensors(10, names=INSECT_SENSORS[::-1])) is None  # other sensor columns
    assert node.last_tick == 9
    assert node.answer(sensors(10)).tick == 10


def test_tick_zero_after_others_is_a_new_run():
    node = BrainNode(CIRCUIT)
    fresh = [actions(node.answer(sensors(t))) for t in range(200)]
    learned = node.brain.engine.get_weights().copy()
    again = [actions(node.answer(sensors(t))) for t in range(200)]
    assert not np.array_equal(learned, initial_weights())  # the first run changed the weights
    np.testing.assert_array_equal(node.brain.engine.get_weights(), learned)  # and the second, from scratch, the same
    for a, b in zip(fresh, again):
        np.testing.assert_array_equal(a, b)


def initial_weights():
    return Brain(CIRCUIT, INSECT_SENSORS, tuple(CIRCUIT.actuators), agents=AGENTS).engine.get_weights()
