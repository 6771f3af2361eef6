"""Circuit files: the shipped ones load as the paper (fig. 2, 4, 6, 7) and the SpikingLab NetLogo demo
give them (docs/circuits.md); wrong ones name file, entry and problem."""

import pytest

from services.brain.circuit import CircuitError, load_circuit

INSECT_SYNAPSES = {
    # the paper's fig. 7 as the NetLogo demo codes it: (weight, delay, inhibitory, plastic)
    **{f"{a}->{m}": (5.0, 3, False, True) for a in ("BLACK", "RED", "GREEN") for m in ("PAIN", "REWARD")},
    "PAIN->REWARD": (22.0, 3, True, False),
    "REWARD->PAIN": (8.0, 3, True, False),
    "PAIN->ROTATE": (11.0, 3, False, False),
    "REWARD->MOVE": (11.0, 3, False, False),
    "H1->H2": (15.0, 2, False, False),
    "H2->H1": (15.0, 3, False, False),
    "H1->REWARD": (3.5, 3, False, False),
    **{
        f"{i}->{n}": (20.0, 0, False, False)
        for i, n in (
            ("smell_black", "BLACK"),
            ("smell_red", "RED"),
            ("smell_green", "GREEN"),
            ("nociceptor", "PAIN"),
            ("reward", "REWARD"),
            ("kick", "H1"),
        )
    },
}


def test_insect_is_the_circuit_of_the_model():
    c = load_circuit("insect")
    got = {c.synapse_label(k): (s.weight, s.delay, s.inhibitory, s.plastic) for k, s in enumerate(c.synapses)}
    assert got == INSECT_SYNAPSES
    types = dict(zip(c.neuron_names, (t.name for t in c.neuron_types)))
    assert types.pop("H1") == types.pop("H2") == "pacemaker"
    assert set(types.values()) == {"regular"}
    assert c.sensors == {"smell_black": 0, "smell_red": 1, "smell_green": 2, "pain": 3, "reward": 4}
    assert c.actuators == {"rotate": "ROTATE", "move": "MOVE"}
    assert c.inputs[c.input_index("kick")].at_start == 1.0


@pytest.mark.parametrize("name", ["conditioning", "association", "two_actions"])
def test_building_blocks_load(name):
    c = load_circuit(name)
    assert c.plastic_synapses


GOOD = """
[neurons]
A = "regular"
B = "regular"

[inputs.a_in]
target = "A"

[[synapses]]
from = "A"
to = "B"
weight = 5
delay = 3
plastic = true
"""


@pytest.mark.parametrize(
    "old,new,entry,problem",
    [
        ('to = "B"', 'to = "Q"', "synapses[0] (A -> Q)", "unknown neuron 'Q'"),
        ('from = "A"', 'from = "Z"', "synapses[0] (Z -> B)", "unknown neuron 'Z'"),
        ("delay = 3", "delay = 0", "synapses[0]", "delay must be >= 1"),
        ('target = "A"', 'target = "A"\ndelay = -1', "inputs.a_in", "delay must be >= 0"),
        ("delay = 3", "delay = 1.5", "synapses[0]", "whole number"),
        ('B = "regular"', 'B = "fancy"', "neurons.B", "unknown neuron type 'fancy'"),
        ("weight = 5", "weight = 16", "synapses[0] (A -> B)", "out of range [1.0, 15.0]"),
        ("weight = 5", "weight = -2", "synapses[0]", "weight must be > 0"),
        ("plastic = true", "plastic = true\ninhibitory = true", "synapses[0]", "not plastic"),
        ("plastic = true", "plastic = true\nstrength = 2", "synapses[0]", "unknown key(s) strength"),
        ("[inputs.a_in]", "[inputs.B]", "inputs.B", "duplicate name 'B'"),
        ('target = "A"', 'target = "X"', "inputs.a_in", "unknown target neuron 'X'"),
        ('from = "A"', 'from = "a_in"', "synapses[0] (a_in -> B)", "an input neuron"),
        ("weight = 5", 'weight = "heavy"', "synapses[0]", "weight must be a number"),
        ("[neurons]", "[neurones]", "top level", "unknown key(s) neurones"),
        ("[neurons]", "types = 3\n[neurons]", "types", "must be a table, got 3"),
        ("[neurons]", 'actuators = "B"\n[neurons]', "actuators", "must be a table, got 'B'"),
    ],
)
def test_wrong_files_name_file_entry_and_problem(tmp_path, old, new, entry, problem):
    assert old in GOOD
    path = tmp_path / "bad.toml"
    path.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(CircuitError) as err:
        load_circuit(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: {entry}: "), msg
    assert problem in msg


def test_duplicate_synapse(tmp_path):
    path = tmp_path / "dup.toml"
    path.write_text(GOOD + '\n[[synapses]]\nfrom = "A"\nto = "B"\nweight = 3\ndelay = 1\n')
    with pytest.raises(
        CircuitError, match=r"synapses\[1\] \(A -> B\): duplicate synapse, already defined in synapses\[0\]"
    ):
        load_circuit(path)


def test_bad_type_values(tmp_path):
    path = tmp_path / "t.toml"
    path.write_text("[types.odd]\ndecay = 1.5\n" + GOOD)
    with pytest.raises(CircuitError, match=r"types.odd: decay must be in \(0, 1\)"):
        load_circuit(path)


def test_not_toml_and_missing_file(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("[neurons\nA = 1")
    with pytest.raises(CircuitError, match=f"{path}: not valid TOML"):
        load_circuit(path)
    with pytest.raises(CircuitError, match="cannot read circuit file"):
        load_circuit(tmp_path / "missing.toml")
    with pytest.raises(CircuitError, match="needs a \\[neurons\\] table"):
        (tmp_path / "empty.toml").write_text("name = 'x'\n")
        load_circuit(tmp_path / "empty.toml")
