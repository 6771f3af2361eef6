"""A lock-step brain whose run stops without its end keeps the learning so far, even when the
run's end interrupts that save (services/brain/lockstep.py)."""

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import services.brain.lockstep as lockstep
from services.brain.circuit import load_circuit
from services.brain.lockstep import LockStep


def brain_mid_run(tmp_path) -> LockStep:
    """A LockStep's run state (no bus): one node at tick 99 of run "r", saving beside weights.npz."""
    brain: Any = LockStep.__new__(LockStep)  # its run state set by hand: Any to the type checker
    circuit = load_circuit("insect")
    node = SimpleNamespace(run="r", last_tick=99, brain=object(), circuit=circuit)
    brain.config, brain.kept, brain.nodes, brain.idle = (
        SimpleNamespace(save=tmp_path / "weights.npz"),
        None,
        {0: node},
        node,
    )
    brain.weights = lambda: np.full((1, len(circuit.synapses)), 5.0)
    return brain


def test_a_sigterm_during_the_save_leaves_the_learning_unsaved_so_the_brain_saves_it_again(tmp_path, monkeypatch):
    """The world's loss and the run's SIGTERM come together: the first save is cut short, and the
    brain's Ctrl-C path must still see learning to keep (it saved nothing when `kept` came first)."""
    brain = brain_mid_run(tmp_path)
    real_save = lockstep.save_weights

    def cut_short(*args, **kwargs):
        monkeypatch.setattr(lockstep, "save_weights", real_save)
        raise KeyboardInterrupt

    monkeypatch.setattr(lockstep, "save_weights", cut_short)
    with pytest.raises(KeyboardInterrupt):
        brain.keep_learning("its world left the bus")
    assert brain.unsaved() and not list(tmp_path.glob("weights-*"))
    brain.keep_learning("the brain was interrupted")
    assert not brain.unsaved() and [p.name for p in tmp_path.glob("weights-*")] == ["weights-r-tick100.npz"]
