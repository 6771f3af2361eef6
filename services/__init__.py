"""spikinglab: a spiking neural network that learns by STDP to steer an insect.

The Python API for scripting experiments, without the bus (docs/api.md):

    from spikinglab import World, brain_for, closed_loop, load_circuit, params_for

    world = World(params_for("paper"), agents=8, seed=1)      # 8 insects, each in its own arena
    brain = brain_for(world, load_circuit("insect").with_learning_rate(0.04))
    closed_loop(world, brain, 20_000)                          # sense -> brain -> act, in lock-step
    world.metrics.collisions, world.metrics.learned_at         # per insect
    brain.engine.get_weights()                                 # [insects, synapses]

The names load lazily, so starting a service does not import the others.
"""

from importlib import import_module

API = {  # name -> module
    "World": "spikinglab.world.world",
    "WorldParams": "spikinglab.world.world",
    "params_for": "spikinglab.world.world",
    "map_world": "spikinglab.world.world",
    "load_circuit": "spikinglab.brain.circuit",
    "Circuit": "spikinglab.brain.circuit",
    "Brain": "spikinglab.brain.brain",
    "Engine": "spikinglab.brain.engine",
    "brain_for": "spikinglab.loop",
    "closed_loop": "spikinglab.loop",
    "evaluate": "spikinglab.loop",
    "AGENT_PARAMS": "spikinglab.params",
    "world_actions": "spikinglab.world.world",
    "noxious_ticks": "spikinglab.learning",
    "learning_time": "spikinglab.learning",
    "DEFINITIONS": "spikinglab.learning",
}
__all__ = sorted(API)


def __getattr__(name: str):
    if name in API:
        return getattr(import_module(API[name]), name)
    raise AttributeError(f"module 'spikinglab' has no attribute {name!r}")
