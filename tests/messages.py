"""One valid message of each kind, for 3 agents: the schema tests' round trips and the fault
tests' mutants start from them."""

import numpy as np

from services.bus.schemas import Array, BrainLayout, BrainState, Control, Motor, Sensors, WorldMap, WorldState

A = 3
GOOD = [
    Sensors(tick=7, names=("smell_black", "pain"), values=Array.of(np.array([[0.4, np.nan]] * A)), seed=4),
    Motor(tick=7, names=("rotate", "move"), actions=Array.of(np.array([[1, 0]] * A, np.uint8))),
    Control(tick=40000, command="end"),
    BrainState(
        tick=7,
        spiked=Array.of(np.zeros((50, A, 15), np.uint8)),
        potentials=Array.of(np.full((50, A, 9), -65, np.float32)),
        weights=Array.of(np.zeros((A, 21))),
    ),
    WorldState(
        tick=7,
        sensor_names=("pain", "reward"),
        sensors=Array.of(np.full((50, A, 2), np.nan)),
        pos=Array.of(np.zeros((50, A, 2))),
        heading=Array.of(np.zeros((50, A))),
        events=Array.of(np.zeros((50, A, 4), np.int64)),
        collisions=Array.of(np.zeros((50, A), np.int64)),
        food=Array.of(np.zeros((50, A), np.int64)),
        changes=Array.of(np.zeros((0, 5), np.int64)),
    ),
    BrainLayout(
        tick=0, circuit="insect", nodes=("A", "B", "a_in"), neurons=2, synapses=("A->B", "a_in->A"), plastic=(0,)
    ),
    WorldMap(tick=0, grid=Array.of(np.zeros((1, 41, 60), np.uint8)), x_min=80, y_min=1),
]
