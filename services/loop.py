"""The closed loop in one process: world and brain stepped in lock-step, no bus in between.

Used by tests, benchmarks, sweeps and `evaluate`; the same world and engine kernels run here as in
the two services, so a run gives the same trajectories, spikes and weights either way. Without a
per-tick callback, and for populations the engine steps on one thread, a whole stretch of ticks
(up to the next collision bin) runs as one compiled call: sense, brain and act fused, no Python
between ticks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from typing import TypedDict, Unpack

import numpy as np
from numba import get_num_threads, njit, prange

from services.brain.brain import Brain, bind
from services.brain.build import TICK
from services.brain.circuit import Circuit, load_circuit
from services.brain.engine import DEFAULT_SEMANTICS, PARALLEL_FROM, range_tick
from services.learning import quarter_collisions
from services.params import AGENT_PARAMS, agent_columns, is_int, setting_count
from services.world.netlogo_setup import spikinglab_setup
from services.world.world import (
    ACTIONS,
    BIN,
    PAIN,
    SENSORS,
    World,
    act_range,
    params_for,
    sense_range,
    touch_range,
    world_actions,
)

# agents; from here the fused loop runs blocks of them on every core: its threads start once per
# stretch of up to BIN ticks, not once per kernel and tick (1.2-1.4 times as fast at 64-128 agents)
BLOCK_FROM = 64


def brain_for(world: World, circuit: Circuit | str, params: Mapping | None = None, **engine_options) -> Brain:
    """A brain for the world's agents; agent a's netlogo order is drawn from the world's seed +
    numbers[a] (as its arena). `circuit`: a Circuit, or a name or path for load_circuit. `params`:
    the brain's per-agent columns (services.params)."""
    circuit = circuit if isinstance(circuit, Circuit) else load_circuit(circuit)
    return Brain(
        circuit,
        SENSORS,
        tuple(circuit.actuators),
        agents=world.agents,
        training=world.training,
        seed=world.seed + world.numbers,
        params=params,
        **engine_options,
    )


def checked_seeds(seeds: Iterable[int]) -> list[int]:
    """The insect numbers as a list; ValueError unless one or more, each a whole number >= 0."""
    if not isinstance(seeds, Iterable) or isinstance(seeds, (str, bytes)):
        raise ValueError(f"seeds: insect numbers, e.g. range(4) or [0, 5] (not a count), got {seeds!r}")
    given = list(seeds)
    if not given or not all(is_int(s) and s >= 0 for s in given):
        raise ValueError(f"seeds: insect numbers, whole numbers >= 0 (one or more), got {given[:8]}")
    return given


def check_ticks(ticks, low: int = 0) -> None:
    if not is_int(ticks) or ticks < low:
        raise ValueError(f"ticks: a whole number >= {low}, got {ticks!r}")


def check_loop(world: World, brain: Brain, ticks, on_tick=None) -> None:
    """ValueError or TypeError, before a tick runs, where world and brain cannot run together for
    `ticks` ticks: the compiled loop indexes both by insect and trusts them to agree."""
    check_ticks(ticks)
    if world.agents != brain.agents:
        raise ValueError(
            f"the world has {world.agents} insect(s), the brain {brain.agents}: make the brain for this "
            f"world (brain_for(world, circuit))"
        )
    if on_tick is not None and not callable(on_tick):
        raise TypeError(f"on_tick: a function of the tick, or None, got {on_tick!r}")


def closed_loop(world: World, brain: Brain, ticks: int, on_tick: Callable[[int], None] | None = None) -> None:
    """Run `ticks` ticks: sense -> brain -> act. `on_tick(t)` is called after each tick."""
    check_loop(world, brain, ticks, on_tick)
    # a large shared arena keeps the per-tick kernels: its fused loop could not split the agents into blocks
    if on_tick is None and (brain.agents < PARALLEL_FROM or not world.shared):
        fused_loop(world, brain, ticks)
        return
    names = brain.action_names
    for t in range(ticks):
        world.act(world_actions(names, brain.step(world.sense())))
        if on_tick is not None:
            on_tick(t)


def wiring(brain: Brain) -> tuple[np.ndarray, np.ndarray]:
    """The world's action columns and the brain's actuator neurons that drive them, pair by pair."""
    bound = [(brain.action_names[c], int(n)) for c, n in zip(brain.action_cols, brain.actuator_neurons)]
    world_cols = np.array([ACTIONS.index(name) for name, _ in bound if name in ACTIONS], np.int64)
    actuators = np.array([n for name, n in bound if name in ACTIONS], np.int64)
    return world_cols, actuators


def fused_loop(
    world: World, brain: Brain, ticks: int, noxious: np.ndarray | None = None, blocks: int | None = None
) -> None:
    """`ticks` ticks of the closed loop as compiled calls, one per stretch up to a bin's end. `noxious`
    ([ticks, agents] uint8): row t set to 1 where an agent's pain sensor was fed in the call's
    tick t (services.learning.noxious_ticks). `blocks`: blocks of agents stepped on threads at
    once, each a whole stretch (default: one per thread from BLOCK_FROM agents in arenas of their
    own, else 1); the same result for any number."""
    check_loop(world, brain, ticks)
    if blocks is None:
        blocks = get_num_threads() if world.agents >= BLOCK_FROM and not world.shared else 1
    if blocks < 1 or (blocks > 1 and world.shared):
        raise ValueError(f"blocks: >= 1, and 1 for a shared arena (its insects race for food), got {blocks}")
    engine = brain.engine
    if noxious is None:
        noxious = np.zeros((0, world.agents), np.uint8)  # none kept
    world_cols, actuators = wiring(brain)
    # as two arrays, not a tuple: a tuple in _fused_parallel's *args reaches its prange body as a
    # "scalar" argument, which numba 0.68 refuses (TypeError: scalar type UniTuple(array...) given)
    senses, drives = np.stack([brain.sensor_cols, brain.input_cols]), np.stack([actuators, world_cols])
    netlogo = engine.semantics == "netlogo"
    done = 0
    while done < ticks:
        n = min(ticks - done, BIN - world.tick % BIN)
        kernel, lead = (_fused, (n,)) if blocks == 1 else (_fused_parallel, (blocks, n))
        kept = noxious[done : done + n]
        kernel(
            *lead,
            netlogo,
            world.tick,
            world.training,
            world.struct,
            world.sensors,
            senses,
            drives,
            brain.feed,
            kept,
            *engine.structs,
        )
        world.advance(n)
        done += n
    bind(engine.spiked, brain.actuator_neurons, brain.action_cols, brain.actions)


@njit(cache=True)
def _fused_block(lo, hi, ticks, netlogo, t0, world_training, w, sensors, senses, drives, feed, noxious, net, st):
    """`ticks` ticks of agents lo..hi-1: the world's kernels on their rows of the WorldStruct `w`,
    the brain's on their columns. `senses`: sensor column senses[0, j] feeds input senses[1, j];
    `drives`: actuator neuron drives[0, j] drives the world's action column drives[1, j]. The
    brain's clock is read, not moved (the caller moves it once)."""
    actions, spiked = w.actions, st.spiked  # spiked: the engine's own [nodes, agents]
    t_brain = st.clock[TICK]
    a_sensors, a_feed = sensors[lo:hi], feed[lo:hi]
    for k in range(ticks):
        sense_range(lo, hi, w, sensors)
        if noxious.shape[0] > 0:
            for a in range(lo, hi):
                noxious[k, a] = sensors[a, PAIN] == sensors[a, PAIN]  # fed: not NaN
        bind(a_sensors, senses[0], senses[1], a_feed)
        range_tick(netlogo, lo, hi, t_brain + k, feed, net, st)
        for a in range(lo, hi):  # not bind(spiked.T, ...): the kernel's own [nodes, agents], 5-10 % faster
            for j in range(drives.shape[1]):
                actions[a, drives[1, j]] = spiked[drives[0, j], a]
        touch_range(lo, hi, w, world_training, t0 + k)
        act_range(lo, hi, w)


@njit(cache=True)
def _fused(ticks, *args):
    """`ticks` ticks of the closed loop for all agents on this thread (`_fused_block`'s arguments after lo, hi)."""
    st = args[-1]
    _fused_block(0, st.v.shape[1], ticks, *args)
    st.clock[TICK] += ticks


@njit(cache=True, parallel=True)
def _fused_parallel(chunks, ticks, *args):
    """The same, each of `chunks` blocks of agents on a thread of its own: agents in arenas of their
    own are independent, so each block runs all `ticks` without waiting for the others."""
    st = args[-1]
    agents = st.v.shape[1]
    for c in prange(chunks):
        _fused_block(c * agents // chunks, (c + 1) * agents // chunks, ticks, *args)
    st.clock[TICK] += ticks


class Setup(TypedDict, total=False):
    """population()'s options, which evaluate() passes on (population() has their defaults)."""

    circuit: str | Circuit
    preset: str
    learned_after: int
    semantics: str
    order: str
    netlogo_seed: int | None


def population(
    params: Mapping,
    seeds,
    *,
    circuit: str | Circuit = "insect",
    preset: str = "paper",
    learned_after: int = 5000,
    semantics: str = DEFAULT_SEMANTICS,
    order: str = "random",
    netlogo_seed: int | None = None,
) -> tuple[World, Brain]:
    """World and brain of every parameter setting on every seed, as one population: agent
    k * len(seeds) + j is setting k on seed j (`evaluate` has the arguments' meaning)."""
    seeds = np.asarray(checked_seeds(seeds), np.int64)
    params_world, grid = params_for(preset, learned_after=learned_after), None
    if netlogo_seed is not None:  # the source's arena and heading for all; the seeds vary the order
        setup = spikinglab_setup(netlogo_seed, params_world)
        params_world, grid = dataclasses.replace(params_world, start_heading=setup.heading), setup.grid
    n = setting_count(params)
    per_agent = {k: np.repeat(v, len(seeds)) for k, v in agent_columns(n, params).items()}  # a setting's seeds together
    side = {s: {k: v for k, v in per_agent.items() if AGENT_PARAMS[k].side == s} for s in ("world", "brain")}
    world = World(
        params_world,
        agents=n * len(seeds),
        seed=0,
        grid=grid,
        numbers=np.tile(seeds, n),
        agent_params=side["world"],
    )
    brain = brain_for(
        world,
        load_circuit(circuit) if not isinstance(circuit, Circuit) else circuit,
        params=side["brain"],
        semantics=semantics,
        order=order,
        netlogo_seed=netlogo_seed,
    )
    return world, brain


def evaluate(
    params: Mapping,
    ticks: int,
    seeds: Iterable[int] = range(4),
    *,
    cluster: str | None = None,
    on_block: Callable[[int], object] | None = None,
    device: str = "cpu",
    **options: Unpack[Setup],
) -> dict[str, np.ndarray]:
    """Train every parameter setting on every seed for `ticks` ticks, all as one population.

    `params`: per-agent parameters (services.params.AGENT_PARAMS, e.g. {"a_plus": [0.01, 0.02],
    "w_max": [15, 10]}), each a number or one value per setting. `seeds`: insect numbers in the
    world of seed 0 (its arenas, headings and netlogo orders; seed s is agent s of `spikinglab run
    --agents`, and the sweep's seed s). Returns arrays [settings, seeds]: "learning_time" (the last
    tick on a noxious patch before `learned_after` ticks off them; -1: not within `ticks`),
    "collisions", "food", and "collisions_last_quarter" (of the run's whole 1,000-tick bins: 0
    in a run of fewer than 1,000 ticks).

    `options` (Setup): the circuit (a name or a Circuit), the world's preset, `learned_after`,
    the engine's semantics and netlogo order, and `netlogo_seed`.

    `cluster`: a Dask scheduler's address (tcp://HOST:PORT, docs/cluster.md); the population runs
    there in blocks, with the same result bit for bit, and `on_block(insects)` is called as each
    block finishes.

    `netlogo_seed`: every insect in the arena and first heading of the SpikingLab source's setup
    after `random-seed N` (docs/netlogo-random.md); the seeds then vary only the netlogo order.

    `device`: "cpu", or "cuda" for an NVIDIA GPU (services/gpu.py, docs/gpu.md): the same results;
    refused in one line (RuntimeError) where numba-cuda or the GPU is missing."""
    if not isinstance(params, Mapping):
        example = {"a_plus": [0.02]}
        raise TypeError(f"params: a mapping of per-agent parameter -> values, e.g. {example}, got {params!r}")
    seeds = checked_seeds(seeds)
    check_ticks(ticks, 1)
    unknown = sorted(set(options) - set(Setup.__annotations__))
    if unknown:
        raise TypeError(f"evaluate: unknown option {unknown[0]!r} (its options: {', '.join(Setup.__annotations__)})")
    if on_block is not None and not callable(on_block):
        raise TypeError(f"on_block: a function called with the insects of each block done, got {on_block!r}")
    if device != "cpu":
        from services.gpu import check_device  # numba.cuda only when the device is asked for

        check_device(device, cluster)
    if cluster is not None:
        from services.cluster import evaluate_on  # the cluster's packages only when one is named

        return evaluate_on(cluster, params, ticks, seeds, on_block, **options)
    world, brain = population(params, seeds, **options)
    if device == "cpu":
        closed_loop(world, brain, ticks)
    else:
        from services.gpu import fused_loop_cuda

        fused_loop_cuda(world, brain, ticks)
    return study_results(world, setting_count(params), len(seeds))


def study_results(world: World, settings: int, seeds: int) -> dict[str, np.ndarray]:
    """evaluate's arrays [settings, seeds] from a population's world after its run."""
    m = world.metrics
    bins = np.array(m.bins, np.int64).reshape(-1, world.agents)
    _, last_quarter = quarter_collisions(bins.T)
    shape = (settings, seeds)
    return {
        "learning_time": m.learned_at.reshape(shape),
        "collisions": m.collisions.reshape(shape),
        "food": m.food.reshape(shape),
        "collisions_last_quarter": last_quarter.reshape(shape),
    }
