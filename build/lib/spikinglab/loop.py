"""The closed loop in one process: world and brain stepped in lock-step, no bus in between.

Used by tests, benchmarks and sweeps; the same World.sense/act and Brain.step run here as in the
two services, so a run gives the same trajectories, spikes and weights either way.
"""

from __future__ import annotations

from collections.abc import Callable

from spikinglab.brain.brain import Brain
from spikinglab.brain.circuit import Circuit
from spikinglab.world.world import SENSORS, World, world_actions


def brain_for(world: World, circuit: Circuit, **engine_options) -> Brain:
    """A brain for the world's agents; the netlogo order is drawn from the world's seed (agent a: seed + a)."""
    return Brain(circuit, SENSORS, tuple(circuit.actuators), agents=world.agents, training=world.training,
                 seed=world.seed, **engine_options)


def closed_loop(world: World, brain: Brain, ticks: int, on_tick: Callable[[int], None] | None = None) -> None:
    """Run `ticks` ticks: sense -> brain -> act. `on_tick(t)` is called after each tick."""
    names = brain.action_names
    for t in range(ticks):
        world.act(world_actions(names, brain.step(world.sense())))
        if on_tick is not None:
            on_tick(t)
