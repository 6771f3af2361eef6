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
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what static tools see; at run time __getattr__ imports a name's module when it is used
    from services.brain.brain import Brain
    from services.brain.circuit import Circuit, load_circuit
    from services.brain.engine import Engine
    from services.cluster import ClusterError
    from services.learning import DEFINITIONS, learning_time, noxious_ticks
    from services.loop import brain_for, closed_loop, evaluate
    from services.params import AGENT_PARAMS
    from services.world.world import World, WorldParams, map_world, params_for, world_actions

API = {  # name -> module
    "World": "services.world.world",
    "WorldParams": "services.world.world",
    "params_for": "services.world.world",
    "map_world": "services.world.world",
    "load_circuit": "services.brain.circuit",
    "Circuit": "services.brain.circuit",
    "Brain": "services.brain.brain",
    "Engine": "services.brain.engine",
    "ClusterError": "services.cluster",
    "brain_for": "services.loop",
    "closed_loop": "services.loop",
    "evaluate": "services.loop",
    "AGENT_PARAMS": "services.params",
    "world_actions": "services.world.world",
    "noxious_ticks": "services.learning",
    "learning_time": "services.learning",
    "DEFINITIONS": "services.learning",
}
__all__ = [  # API's names, written out for static tools (tests/test_api.py checks they agree)
    "AGENT_PARAMS",
    "Brain",
    "Circuit",
    "ClusterError",
    "DEFINITIONS",
    "Engine",
    "World",
    "WorldParams",
    "brain_for",
    "closed_loop",
    "evaluate",
    "learning_time",
    "load_circuit",
    "map_world",
    "noxious_ticks",
    "params_for",
    "world_actions",
]


def __getattr__(name: str):
    if name in API:
        return getattr(import_module(API[name]), name)
    raise AttributeError(f"module 'spikinglab' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The API's names too (a notebook completes them before any is imported)."""
    return sorted({*globals(), *API})
