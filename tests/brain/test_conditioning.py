"""Classical conditioning on the paper's building blocks (fig. 2, fig. 4 and fig. 6)."""

import dataclasses

from services.brain.circuit import load_circuit
from services.brain.conditioning import TRIAL, responds, show, train

from .helpers import phased, relay_circuit

TRIALS = 400  # ~0.017 per pairing at A+ = 0.02 and dt = -2: 5 -> 10 needs ~300


def test_fig2_c_before_u_teaches_c_to_fire_m():
    e = phased(load_circuit("conditioning"))
    assert not responds(e, "c_in") and responds(e, "u_in")
    history = train(e, {"c_in": 0, "u_in": 2}, TRIALS)  # C's pulse reaches M 2 ticks before U's
    weights = [w[0] for w in history]
    assert all(b >= a for a, b in zip(weights, weights[1:]))  # grows monotonically
    assert e.w[0, 0] > 10
    assert responds(e, "c_in")


def test_fig2_reverse_order_does_not_teach():
    e = phased(load_circuit("conditioning"))
    train(e, {"u_in": 0, "c_in": 2}, TRIALS)
    assert e.w[0, 0] == 1.0  # depressed to w_min
    assert not responds(e, "c_in")


def test_fig4_paired_a_learns_unpaired_b_does_not():
    c = load_circuit("association")
    e = phased(c)
    train(e, {"a_in": 0, "u_in": 2, "b_in": 6}, TRIALS)  # A before U, B after M fired
    wa, wb = e.w[0, c.synapse_index("A", "M")], e.w[0, c.synapse_index("B", "M")]
    assert wa > 10 and wb == 1.0
    assert responds(e, "a_in") and not responds(e, "b_in")


def test_fig6_each_action_learns_its_own_stimulus():
    c = load_circuit("two_actions")
    e = phased(c)
    # one trial of 2 x TRIAL ticks: A paired with U1 (action R), later B paired with U2 (action M)
    train(e, {"a_in": 0, "u1_in": 2, "b_in": TRIAL, "u2_in": TRIAL + 2}, TRIALS, period=2 * TRIAL)
    w = {lab: e.w[0, c.synapse_index(*lab.split("->"))] for lab in ("A->R", "A->M", "B->R", "B->M")}
    assert w["A->R"] > 10 and w["B->M"] > 10
    # A never meets an M spike (R fires and inhibits M in its trials): A->M stays where it was
    assert w["A->M"] == 5.0 and w["B->R"] == 5.0
    assert responds(e, "a_in", "R") and not responds(e, "a_in", "M")
    assert responds(e, "b_in", "M") and not responds(e, "b_in", "R")


def test_the_report_gives_each_synapse_its_own_starting_weight(capsys):
    circuit = relay_circuit()  # C -> M plastic, weight 5
    start = dataclasses.replace(circuit.synapses[0], weight=3.0)
    circuit = dataclasses.replace(circuit, synapses=(start, *circuit.synapses[1:]))
    show("C before U", circuit, {"c_in": 0, "u_in": 2}, [("c_in", "M")], trials=2)
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "weight" in ln)
    assert line.split()[:3] == ["C->M", "weight", "3.00"]
