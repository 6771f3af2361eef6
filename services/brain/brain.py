"""The brain: an Engine plus the circuit's bindings (sensor columns in, actuator spikes out)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .circuit import Circuit
from .engine import Engine


def check_sensors(circuit: Circuit, sensors) -> None:
    """ValueError unless every sensor the circuit binds is among `sensors` (what the world publishes)."""
    unknown = sorted(set(circuit.sensors) - set(sensors))
    if unknown:
        raise ValueError(
            f"circuit {circuit.name!r} binds sensors {unknown} that the world does not "
            f"publish (it publishes {list(sensors)})"
        )


class Brain:
    """Maps the sensor columns a world (or robot) publishes onto the circuit's input neurons, steps
    the engine, and reports which actions fired. Sensors the circuit does not bind are ignored;
    actions it does not bind never fire."""

    def __init__(
        self,
        circuit: Circuit,
        sensors: tuple[str, ...],
        actions: tuple[str, ...],
        agents: int = 1,
        training: bool = True,
        **engine_options,
    ):
        """`engine_options`: the Engine's semantics, order, seed (and without, for ablations)."""
        self.circuit, self.sensor_names, self.action_names = circuit, tuple(sensors), tuple(actions)
        check_sensors(circuit, sensors)
        self.engine = Engine(circuit, agents=agents, training=training, **engine_options)
        # the bindings, as column indices: sensor_cols[j] of the sensors feeds input neuron input_cols[j];
        # a spike of neuron actuator_neurons[j] sets column action_cols[j] of the actions
        bound = circuit.sensors
        self.sensor_cols = np.array([sensors.index(s) for s in bound], dtype=np.int64)
        self.input_cols = np.array(list(bound.values()), dtype=np.int64)
        self.action_cols = np.array([actions.index(a) for a in circuit.actuators if a in actions], dtype=np.int64)
        self.actuator_neurons = np.array(
            [circuit.neuron_index(n) for a, n in circuit.actuators.items() if a in actions], dtype=np.int64
        )
        self.feed = np.full((agents, len(circuit.inputs)), np.nan)
        self.actions = np.zeros((agents, len(actions)), dtype=np.uint8)

    @property
    def agents(self) -> int:
        return self.engine.agents

    def step(self, sensors: np.ndarray) -> np.ndarray:
        """One tick: sensors [A, len(sensors)] (NaN: nothing sensed) -> actions [A, len(actions)]."""
        if sensors.shape != (self.agents, len(self.sensor_names)):  # bind() reads without bounds checks
            raise ValueError(f"sensors of shape {sensors.shape}, expected {(self.agents, len(self.sensor_names))}")
        bind(sensors, self.sensor_cols, self.input_cols, self.feed)
        spiked = self.engine.step(self.feed)
        bind(spiked, self.actuator_neurons, self.action_cols, self.actions)
        return self.actions


@njit(cache=True, inline="always")  # inlined into the fused loop as its loops were
def bind(source, source_cols, target_cols, target):
    """target[:, target_cols] = source[:, source_cols] for every agent (row): compiled, as numpy's
    two fancy-indexing calls cost 2 us each at one agent and many times that on a lock-step tick."""
    for a in range(target.shape[0]):
        for j in range(source_cols.shape[0]):
            target[a, target_cols[j]] = source[a, source_cols[j]]
