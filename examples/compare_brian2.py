"""The insect circuit in Brian2's C++ standalone mode, on the feeds of `spikinglab bench engine`:
Brian2's agent-ticks/s on this machine, to set beside the engine's (docs/results.md).

A agents are A copies of the circuit (services/brain/circuits/insect.toml) in one NeuronGroup of
A x 9 neurons, with the circuit's synapses, weights, delays, floors and refractory periods, and
STDP on its plastic synapses as Brian2 writes it (a trace per side, the circuit's A+, A-, tau+ and
tau-). One tick is one step of 1 ms. The sensor feeds are the benchmark's (spikinglab/bench/feeds.py: each
sensor feeds a value in [0, 4) with probability 0.3 a tick, seed 0), turned into the input
neurons' spike times by their latency code before the run, so Brian2 reads them from a
SpikeGeneratorGroup; the pacemaker's kick is fed at tick 0. The timing is Brian2's own of the run
in the compiled program (`device._last_run_time`), without the C++ compile.

Not the engine's semantics: Brian2 updates every neuron by exact integration each step, delivers
pulses after thresholds, and its STDP is by traces (NetLogo's: over each neuron's history), so the
spikes differ; the spikes per agent-tick printed say whether the activity is alike.

Brian2 is not a dependency of spikinglab (its 2.9 needs numpy < 2.3); in a venv of its own, from
the repository's root:

    python3 -m venv /tmp/brian2 && /tmp/brian2/bin/pip install brian2 'numpy<2.3' msgspec
    PYTHONPATH=. /tmp/brian2/bin/python examples/compare_brian2.py --threads 1 2
"""

from __future__ import annotations

import argparse
import json
import tempfile

import numpy as np

from services.brain.circuit import Circuit, load_circuit
from spikinglab.bench.feeds import random_feeds

# Brian2 delivers a step's pulses after its thresholds, the engine before its neurons fire: pulses
# are sent a step early (delays one less, input spikes one step before), so spikes come at the
# engine's ticks
LATE = 1
# a neuron: decay toward rest, held while refractory; its type's parameters
NEURON = """dv/dt = (rest - v) / tau : 1 (unless refractory)
rest : 1 (constant)
vt : 1 (constant)
tau : second (constant)
v_refr : 1 (constant)
v_floor : 1 (constant)
ref : second (constant)"""
# on_pre (and on_post) of each kind of synapse; a pulse changes nothing at a refractory neuron
SYNAPSES = {
    "plastic": {
        "model": """w : 1
        dapre/dt = -apre / taupre : 1 (event-driven)
        dapost/dt = -apost / taupost : 1 (event-driven)""",
        "on_pre": """v_post += w * int(not_refractory_post)
        apre += a_plus
        w = clip(w + apost, w_min, w_max)""",
        "on_post": """apost -= a_minus
        w = clip(w + apre, w_min, w_max)""",
    },
    # refractory, v is v_refr, never under the floor: the clip changes nothing then
    "inhibitory": {
        "model": "w : 1",
        "on_pre": "v_post = clip(v_post - w * int(not_refractory_post), v_floor_post, inf)",
    },
    "excitatory": {"model": "w : 1", "on_pre": "v_post += w * int(not_refractory_post)"},
}


def kind_of(syn) -> str:
    return "plastic" if syn.plastic else "inhibitory" if syn.inhibitory else "excitatory"


def input_spikes(circuit: Circuit, feeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index, tick) of every input neuron's spike (index agent x inputs + input): an idle input fed
    x at t spikes at t + floor(x) and ignores feeds until then; the kick is fed at tick 0."""
    feeds = feeds.copy()
    for k, spec in enumerate(circuit.inputs):
        if spec.at_start is not None:
            feeds[0, :, k] = spec.at_start
    ticks, agents, inputs = feeds.shape
    due = np.full((agents, inputs), -1)  # the tick an input will spike at; -1: idle
    indices, times = [], []
    for t in range(ticks):
        fed = (due < 0) & ~np.isnan(feeds[t])
        due[fed] = t + np.floor(feeds[t][fed]).astype(int)
        now = np.flatnonzero(due == t)
        indices.append(now)
        times.append(np.full(now.size, t))
        due[due == t] = -1
    return np.concatenate(indices), np.concatenate(times)


def brian2_rates(circuit: Circuit, feeds: np.ndarray, threads: int, runs: int) -> tuple[list[float], float]:
    """Agent-ticks/s of `runs` runs of Brian2's compiled program, and its spikes per agent-tick."""
    import brian2 as b2  # pyright: ignore[reportMissingImports]  # not a dependency: its own venv

    for name in ("brian2.codegen.generators.base", "brian2.devices.cpp_standalone.device.openmp"):
        b2.BrianLogger.suppress_name(name)  # the clip's order (see SYNAPSES) and OpenMP "not yet well tested"
    b2.device.reinit()
    b2.device.activate()
    b2.set_device("cpp_standalone", build_on_run=False)
    b2.prefs.devices.cpp_standalone.openmp_threads = threads if threads > 1 else 0  # 0: no OpenMP
    b2.defaultclock.dt = 1 * b2.ms
    ticks, agents, _ = feeds.shape
    neurons = neuron_group(b2, circuit, agents)
    groups, inputs, sent = synapse_groups(b2, circuit, neurons, feeds)
    spikes = b2.SpikeMonitor(neurons, record=False)
    network = b2.Network(neurons, inputs, spikes, *groups)
    network.run(ticks * b2.ms, namespace={})
    b2.device.build(directory=tempfile.mkdtemp(prefix="brian2-insect-"), run=False, compile=True)
    rates = []
    for _ in range(runs):  # the compiled program run again: Brian2 times its run, set-up excluded
        b2.device.run()
        rates.append(agents * ticks / b2.device._last_run_time)
    # as the engine counts them: the circuit's neurons and the input neurons
    return rates, (int(spikes.num_spikes) + sent) / agents / ticks


def neuron_group(b2, circuit: Circuit, agents: int):
    """Every agent's neurons, agent by agent, with their types' parameters."""
    neurons = b2.NeuronGroup(
        agents * len(circuit.neuron_names),
        NEURON,
        threshold="v >= vt",
        reset="v = v_refr",
        refractory="ref",
        method="exact",
    )
    each = lambda field: np.tile([getattr(t, field) for t in circuit.neuron_types], agents)  # noqa: E731
    neurons.rest, neurons.v, neurons.vt = each("rest"), each("rest"), each("threshold")
    neurons.tau = -1 / np.log1p(-each("decay")) * b2.ms  # exp(-1 ms / tau) = 1 - decay: the per-tick decay
    neurons.v_refr, neurons.v_floor = each("refractory_potential"), each("floor")
    neurons.ref = each("refractory_period") * b2.ms
    return neurons


def synapse_groups(b2, circuit: Circuit, neurons, feeds: np.ndarray) -> tuple[list, object, int]:
    """One Synapses of each kind for every agent's synapses of that kind, the input neurons' spikes
    (a SpikeGeneratorGroup) and their Synapses, and how many spikes the generator sends."""
    _, agents, n_in = feeds.shape
    agent_base = np.arange(agents) * len(circuit.neuron_names)
    learner = circuit.neuron_types[next(syn.post for syn in circuit.synapses if syn.plastic)]  # one type learns
    stdp = {"taupre": learner.tau_plus * b2.ms, "taupost": learner.tau_minus * b2.ms, "a_plus": learner.a_plus}
    stdp |= {"a_minus": learner.a_minus, "w_min": learner.w_min, "w_max": learner.w_max}
    groups = []
    for kind, arguments in SYNAPSES.items():
        chosen = [syn for syn in circuit.synapses[: len(circuit.synapses) - n_in] if kind_of(syn) == kind]
        group = b2.Synapses(neurons, neurons, **arguments, namespace=stdp if kind == "plastic" else {})
        group.connect(
            i=np.concatenate([agent_base + syn.pre for syn in chosen]),
            j=np.concatenate([agent_base + syn.post for syn in chosen]),
        )
        group.w = np.repeat([syn.weight for syn in chosen], agents)
        group.delay = np.repeat([max(syn.delay - LATE, 0) for syn in chosen], agents) * b2.ms
        groups.append(group)
    index, tick = input_spikes(circuit, feeds)
    sent = tick >= LATE  # those of tick 0 cannot be sent a step early
    inputs = b2.SpikeGeneratorGroup(agents * n_in, index[sent], (tick[sent] - LATE) * b2.ms)
    group = b2.Synapses(inputs, neurons, **SYNAPSES["excitatory"])
    targets = [circuit.neuron_names.index(spec.target) for spec in circuit.inputs]
    group.connect(i=np.arange(agents * n_in), j=(agent_base[:, None] + targets).ravel())
    group.w = np.tile([spec.weight for spec in circuit.inputs], agents)
    return [*groups, group], inputs, int(sent.sum())


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--agents", type=int, default=1000, help="copies of the circuit (default 1,000)")
    p.add_argument("--ticks", type=int, default=5000, help="ticks of the run (default 5,000)")
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="OpenMP threads, a run each (default 1 2)")
    p.add_argument(
        "--runs",
        type=int,
        default=3,
        help="runs of the compiled program for each thread count, the best reported (default 3)",
    )
    args = p.parse_args(argv)
    circuit = load_circuit("insect")
    feeds = random_feeds(np.random.default_rng(0), circuit, args.ticks, args.agents)
    result = {}
    for threads in args.threads:
        rates, spikes = brian2_rates(circuit, feeds, threads, args.runs)
        print(
            f"Brian2 C++ standalone, {threads} thread(s): A = {args.agents} {max(rates):,.0f} agent-ticks/s "
            f"(best of {args.runs}: {', '.join(f'{r / 1e6:.2f}' for r in rates)} M), {spikes:.2f} spikes per agent-tick"
        )
        result[f"brian2_{threads}_threads_agent_ticks_per_s"] = round(max(rates))
        result["brian2_spikes_per_agent_tick"] = round(spikes, 3)
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
