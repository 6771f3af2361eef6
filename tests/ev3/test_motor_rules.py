"""The gateway's motor and safety rules, without the bus or a robot (MotorRules, motor_actions)."""

import re

import numpy as np
import pytest

from services.bus.schemas import Array, BusError, Motor
from services.ev3_gateway.service import MotorCall, MotorRules, motor_actions
from services.vocabulary import INSECT_ACTIONS

ROTATE, MOVE, BOTH = {"rotate": 1, "move": 0}, {"rotate": 0, "move": 1}, {"rotate": 1, "move": 1}


def rules_with_brain(now=0.0) -> MotorRules:
    rules = MotorRules(move_ms=500, spin_ms=100, timeout_s=0.25)
    assert rules.decide(now, True, None) is None  # the brain arrives: nothing to do yet
    return rules


def call_at(rules, now, brain_alive, actions=None) -> MotorCall:
    """rules.decide's answer, where the test expects a call."""
    call = rules.decide(now, brain_alive, actions)
    assert call is not None, f"no motor call at {now} s"
    return call


def made(rules, now, actions) -> MotorCall:
    call = call_at(rules, now, True, actions)
    rules.made(call, now)
    return call


def test_no_brain_no_motion():
    rules = MotorRules(move_ms=500, spin_ms=100, timeout_s=0.25)
    for now in (0.0, 1.0, 5.0):  # a motor message with no brain's token on the bus is not followed
        assert rules.decide(now, False, MOVE) is None
        assert rules.decide(now, False, ROTATE) is None
    assert rules.stopped


def test_spikes_become_timed_commands_and_rotate_wins():
    rules = rules_with_brain()
    assert rules.decide(0.0, True, MOVE) == MotorCall("forward", (500,))
    assert rules.decide(0.0, True, ROTATE) == MotorCall("spin", (100, 1))
    assert rules.decide(0.0, True, BOTH) == MotorCall("spin", (100, 1))
    assert rules.decide(0.0, True, {"rotate": 0, "move": 0}) is None
    assert rules.decide(0.0, True, {"jump": 1}) is None  # an action the robot does not have


NOTHING = {"rotate": 0, "move": 0}  # the brain's heartbeat: an empty motor message


def test_a_silent_brain_stops_the_walk_within_the_timeout():
    rules = rules_with_brain()
    made(rules, 1.0, MOVE)  # forward until 1.5 s, but the brain is not heard after 1.0 s (stalled, link broken)
    assert rules.decide(1.24, True, None) is None
    stop = call_at(rules, 1.26, True)
    assert stop.call == "stop" and "no word from the brain for 250 ms" in stop.why
    rules.made(stop, 1.26)
    assert rules.decide(5.0, True, None) is None  # stopped once, not again and again


def test_a_heard_brain_walks_until_the_command_ended_and_the_timeout_passed():
    rules = rules_with_brain()
    made(rules, 1.0, MOVE)  # forward until 1.5 s
    for now in np.arange(1.05, 1.72, 0.05):  # heartbeats every 50 ms
        assert rules.decide(now, True, NOTHING) is None
        assert rules.decide(now + 0.01, True, None) is None  # still walking, then within the 250 ms grace
    assert rules.decide(1.76, True, NOTHING) is None
    stop = call_at(rules, 1.77, True)
    assert stop.call == "stop" and "no motor command within 250 ms after the last ended" in stop.why


def test_a_new_command_extends_the_walk():
    rules = rules_with_brain()
    made(rules, 1.0, MOVE)
    made(rules, 1.2, MOVE)  # replaces the first: ends at 1.7
    assert rules.decide(1.4, True, NOTHING) is None
    assert rules.decide(1.6, True, NOTHING) is None
    assert rules.decide(1.9, True, NOTHING) is None
    assert call_at(rules, 1.96, True).call == "stop"


def test_a_stop_that_did_not_reach_the_robot_is_asked_again():
    rules = rules_with_brain()
    made(rules, 1.0, ROTATE)  # spin until 1.1
    assert rules.decide(1.3, True, NOTHING) is None
    assert call_at(rules, 1.4, True).call == "stop"  # the link was down: not made
    assert call_at(rules, 1.5, True).call == "stop"


def test_losing_the_brain_stops_at_once_and_ignores_commands_until_it_is_back():
    rules = rules_with_brain()
    made(rules, 1.0, MOVE)
    stop = call_at(rules, 1.1, False)  # mid-walk
    assert stop.call == "stop" and "liveliness" in stop.why
    rules.made(stop, 1.1)
    assert rules.decide(1.2, False, MOVE) is None
    assert rules.decide(1.3, True, MOVE) == MotorCall("forward", (500,))


def motor(actions, run="r1") -> Motor:
    return Motor(tick=7, names=INSECT_ACTIONS, actions=Array.of(np.array(actions, np.uint8).reshape(-1, 2)), run=run)


@pytest.mark.parametrize("rows,expected", [([[1, 0]], {"rotate": 1, "move": 0}), ([[0, 1]], {"rotate": 0, "move": 1})])
def test_motor_messages_for_this_runs_robot(rows, expected):
    assert motor_actions(motor(rows), "r1") == expected


@pytest.mark.parametrize(
    "message,reason",
    [
        (motor([]), "does not fit the run: actions of shape [0, 2]"),  # for no robot: once an IndexError in the thread
        (motor([[1, 0], [0, 1]]), "does not fit the run: actions of shape [2, 2]"),  # two robots: which one is this?
        (motor([[0, 1]], run="r0"), "another run: motor for run 'r0'"),  # an old run's, or a forger's guess
    ],
)
def test_other_motor_messages_are_refused(message, reason):
    with pytest.raises(BusError, match=re.escape(reason)):
        motor_actions(message, "r1")
