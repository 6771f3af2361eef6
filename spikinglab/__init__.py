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
    "World": "services.world.world",
    "WorldParams": "services.world.world",
    "params_for": "services.world.world",
    "map_world": "services.world.world",
    "load_circuit": "services.brain.circuit",
    "Circuit": "services.brain.circuit",
    "Brain": "services.brain.brain",
    "Engine": "services.brain.engine",
    "brain_for": "services.loop",
    "closed_loop": "services.loop",
    "evaluate": "services.loop",
    "AGENT_PARAMS": "services.params",
    "world_actions": "services.world.world",
    "noxious_ticks": "services.learning",
    "learning_time": "services.learning",
    "DEFINITIONS": "services.learning",
}
__all__ = sorted(API)


def __getattr__(name: str):
    if name in API:
        return getattr(import_module(API[name]), name)
    raise AttributeError(f"module 'spikinglab' has no attribute {name!r}")
