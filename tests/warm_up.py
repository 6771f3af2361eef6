"""The kernels that the services and the in-process loop compile, compiled once into the kernel
cache (services/kernel_cache.py) before the tests start. On a cold cache (a fresh machine, or any
change under services/) every process of every test would compile them at its first tick, several
at once on two cores, and a test's wait for a run to be under way would count minutes of
compiling (`bash scripts/test.sh -k launch` failed two launch files so). tests/conftest.py runs
it as two processes at once, one for each size: `python -m tests.warm_up AGENTS` (with none, both
sizes in turn)."""

from __future__ import annotations

import sys

from services.params import PARALLEL_FROM

SIZES = (1, PARALLEL_FROM)  # agents: the serial kernels, and those across cores


def main(agents: int) -> None:
    from services.brain.circuit import load_circuit  # here: conftest imports SIZES alone
    from services.loop import brain_for, closed_loop
    from services.world.world import World

    circuit = load_circuit("insect")
    for semantics in ("netlogo", "phased"):
        world = World(seed=1, agents=agents)
        brain = brain_for(world, circuit, semantics=semantics)
        closed_loop(world, brain, 2)  # the fused loop of run, evaluate and sweep
        closed_loop(world, brain, 2, on_tick=lambda tick: None)  # the services' kernels, tick by tick


if __name__ == "__main__":
    for size in map(int, sys.argv[1:]) if sys.argv[1:] else SIZES:
        main(size)
