"""The engine's builder: a Circuit and per-agent parameters turned into the arrays its kernels step.

The builder lays everything out once (columns, flags, learning tables, the netlogo turns' data);
services/brain/engine.py only steps it, as nengo keeps its builder apart from its simulator. Two
named structures cross into the compiled kernels: the Network (what a run does not change) and the
State (what a tick changes). Each is a numba structref as well as a dataclass of numpy arrays
(the same memory): a kernel call passes two objects instead of 17 arrays, which is most of what a
one-agent tick costs (docs/tick.md, "Layout and speed").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numba import njit
from numba.core import types
from numba.experimental import structref

from services.params import LEARNING_FIELDS, AgentValueError

from .circuit import Circuit
from .netlogo_stream import STREAM_TURNS, source_order
from .stdp import stdp_table

HISTORY = 30  # arrivals a neuron remembers since its last spike (oldest dropped)
NEVER = -(2**62)  # last-spike tick of a neuron that has not fired yet
SYN_BITS = 16  # a history entry packs (arrival tick << SYN_BITS) | synapse index
SYN_MASK = (1 << SYN_BITS) - 1
SEMANTICS = ("phased", "netlogo")
DEFAULT_SEMANTICS = "netlogo"  # the original's engine: the only one that learns in every setting (docs/results.md)
# netlogo: neurons per tick in a seeded random order, in file order, or drawn from NetLogo's own
# stream as the SpikingLab source draws them (services/brain/netlogo_stream.py)
ORDERS = ("random", "file", "netlogo-stream")
# netlogo rules, each of which can be switched off alone to measure what it does (docs/results.md)
SHUFFLE, COUNT_FROM_SEND, REOPEN_IN_TURN, DT0_AGAIN, STREAM = 1, 2, 4, 8, 16
# The turns neuron by neuron across agents (engine._netlogo_by_receiver): where no pulse reaches its
# post in the tick it is sent and the order is drawn before the turns (not NetLogo's own stream)
BY_RECEIVER = 32
# ... from this many agents: below, their loops are too short to pay for the passes per neuron (insect
# circuit, one thread, agent-ticks/s by receiver against one by one: A = 8 4.7 M against 5.4 M,
# A = 16 7.6 against 7.0, A = 128 15.0 against 8.7; EPYC, 2026-11-26)
BY_RECEIVER_FROM = 16
NETLOGO_RULES = {
    "delay_count": COUNT_FROM_SEND,  # a pulse's count-down starts in the sending tick (else: the next)
    "reopen": REOPEN_IN_TURN,  # a refractory neuron opens in its turn (else: at the next tick's start)
    "dt0": DT0_AGAIN,  # arrivals at dt = 0 potentiate again at every later arrival (else: once)
}

# npar columns: per neuron, these fields of its type (circuit.NeuronType), then the offset of dt = 0
# in W(dt)
NEURON_COLUMNS = ("rest", "threshold", "decay", "refractory_potential", "refractory_period", "floor")
REST, THRESHOLD, DECAY, REFR_V, REFR_PERIOD, FLOOR, STDP_OFFSET = range(len(NEURON_COLUMNS) + 1)
# learning: stdp[group, profile] holds w_min, w_max, then the table W(dt) (stdp.py), for the agents of
# one group of per-agent parameters (group[a]) and the neurons of one profile (profile[n])
LO, HI, TABLE = 0, 1, 2
# syn columns; flags bits
PRE, POST, DELAY, FLAGS = 0, 1, 2, 3
INHIBITORY, PLASTIC = 1, 2
# counters planes [3, nodes, A] (int32): for neurons ...
REFR_LEFT, HIST_LEN, REFRACTORY = 0, 1, 2  # REFRACTORY: netlogo's state flag (its counter may be <= 0)
# ... and for input neurons (the nodes after the neurons): ticks counted, pulses left, latency
COUNT, LEFT, LATENCY = 0, 1, 2
# inpar columns: per input neuron
PULSES, AT_START = 0, 1
# clock: [tick, training]
TICK, TRAINING = 0, 1


@dataclass(frozen=True)
class Network:
    """What a run does not change. The phased semantics ignores the fields from out_start on."""

    syn: np.ndarray  # [synapses, PRE..FLAGS] int64: network synapses, then one per input neuron
    npar: np.ndarray  # [neurons, REST..STDP_OFFSET]
    inpar: np.ndarray  # [inputs, PULSES..AT_START]
    stdp: np.ndarray  # [groups, profiles, LO, HI, W(dt)...]
    group: np.ndarray  # [A]: agent a's row of stdp
    profile: np.ndarray  # [neurons]: neuron n's column of stdp
    learns: np.ndarray  # [neurons] bool: a plastic synapse comes in (no other neuron ever has a history)
    out_start: np.ndarray  # [neurons + 1] uint64: neuron n's outgoing synapses are out_syn[out_start[n]:out_start[n+1]]
    out_syn: np.ndarray  # [network synapses] uint64
    in_start: np.ndarray  # [neurons + 1] uint64: neuron n's incoming synapses are in_syn[in_start[n]:in_start[n+1]]
    in_syn: np.ndarray  # [network synapses] uint64 by post, then pre, then file order (a turn's deliveries)
    order_key: np.ndarray  # [A] uint64: the hash of agent a's seed, for its netlogo order
    order_jump: np.ndarray  # [2, neurons] uint64: the order's LCG k steps on from r is r * [0, k] + [1, k]
    rules: int  # the NETLOGO_RULES bits in force, and SHUFFLE or STREAM for those orders
    stream_order: np.ndarray  # [neurons] uint64 for netlogo-stream: the neurons in NetLogo's agentset order

    def struct(self) -> NetworkStruct:
        return _network_struct(*(getattr(self, f.name) for f in dataclasses.fields(self)))


@dataclass(frozen=True)
class State:
    """What a tick changes; the agent axis last (each phase is a loop across agents)."""

    clock: np.ndarray  # [TICK, TRAINING] int64
    v: np.ndarray  # [neurons, A] membrane potentials
    w: np.ndarray  # [synapses, A] weights
    counters: np.ndarray  # [3, nodes, A] int32: REFR_LEFT.. for neurons, COUNT.. for input neurons
    last_spike: np.ndarray  # [neurons, A] int64
    hist: np.ndarray  # [A, neurons, HISTORY + 1] int64: per event, agent-major (netlogo keeps 31)
    ring: np.ndarray  # [ring length, synapses, A] uint8: pulses in flight, slot = arrival tick & mask
    spiked: np.ndarray  # [nodes, A] uint8: who spiked in the last tick
    stream: np.ndarray  # [A, netlogo_stream.STREAM_TURNS + neurons] uint32 for netlogo-stream, else [A, 0]

    def struct(self) -> StateStruct:
        return _state_struct(*(getattr(self, f.name) for f in dataclasses.fields(self)))


@structref.register
class NetworkType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


@structref.register
class StateType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class NetworkStruct(structref.StructRefProxy):
    """A Network as the kernels take it (its arrays, not copies)."""


class StateStruct(structref.StructRefProxy):
    """A State as the kernels take it (its arrays, not copies)."""


structref.define_proxy(NetworkStruct, NetworkType, [f.name for f in dataclasses.fields(Network)])
# The netlogo turns index by neuron in a random order, and read and write these flat views, one index
# each (n * A + a; a ring slot's synapses at slot * S * A): fewer live strides than a register file
# holds. Made once with the struct: made per call, they cost one agent's run() a quarter of its speed.
FLAT_VIEWS = ("v_flat", "w_flat", "spiked_flat", "last_spike_flat", "refractory_flat", "refr_left_flat")
FLAT_VIEWS += ("hist_len_flat", "ring_flat")
# Scratch the kernels overwrite, made once with the struct (not state: never saved):
# feed_column [A] float64, one input neuron's feed for its agents, contiguous (engine._feed_and_inputs);
# due_flat [neurons * A] uint8 at n * A + a, whether neuron n has pulses due now; draws_flat
# [(neurons + 1) * A] uint64, the random order's draws (engine._netlogo_range).
# places [A] uint64, the place of each neuron's turn in agent a's order (4 bits each: up to 16 neurons)
# arrived_flat [2 * A] uint64, one neuron's pulses due now, a bit per incoming synapse: from the
# turns before its own (row 0) and after; agent_list [A] uint64, the agents with any of them
# (engine._netlogo_by_receiver).
SCRATCH = ("feed_column", "due_flat", "draws_flat", "places", "arrived_flat", "agent_list")
structref.define_proxy(
    StateStruct, StateType, [f.name for f in dataclasses.fields(State)] + list(FLAT_VIEWS) + list(SCRATCH)
)


# Made in compiled code, from numba's cache: a proxy's own constructor compiles anew in every process.
@njit(cache=True)
def _network_struct(*fields):  # Network's, in its order
    return NetworkStruct(*fields)


@njit(cache=True)
def _state_struct(clock, v, w, counters, last_spike, hist, ring, spiked, stream):
    flat = (v.reshape(-1), w.reshape(-1), spiked.reshape(-1), last_spike.reshape(-1))
    counters_flat = (counters[REFRACTORY].reshape(-1), counters[REFR_LEFT].reshape(-1), counters[HIST_LEN].reshape(-1))
    arrays = (clock, v, w, counters, last_spike, hist, ring, spiked, stream)
    agents = v.shape[1]
    scratch = (np.empty(agents), np.empty(v.size, np.uint8), np.empty(v.size + agents, np.uint64))
    by_receiver = (np.empty(agents, np.uint64), np.empty(2 * agents, np.uint64), np.empty(agents, np.uint64))
    return StateStruct(*arrays, *flat, *counters_flat, ring.reshape(-1), *scratch, *by_receiver)


def check_options(agents: int, semantics: str, order: str, without, netlogo_seed: int | None = None) -> None:
    """ValueError naming a wrong engine option."""
    if agents < 1:
        raise ValueError(f"agents must be >= 1, got {agents}")
    if semantics not in SEMANTICS:
        raise ValueError(f"semantics must be one of {', '.join(SEMANTICS)}, got {semantics!r}")
    if order not in ORDERS:
        raise ValueError(f"order must be one of {', '.join(ORDERS)}, got {order!r}")
    if order == "netlogo-stream" and (semantics != "netlogo" or netlogo_seed is None):
        raise ValueError(
            "order netlogo-stream draws from NetLogo's stream as the source's setup leaves it: it needs "
            "--semantics netlogo and --netlogo-seed N"
        )
    unknown = sorted(set(without) - set(NETLOGO_RULES))
    if unknown:
        raise ValueError(f"without: NetLogo rules are {', '.join(NETLOGO_RULES)}, got {', '.join(unknown)}")
    if without and semantics != "netlogo":
        raise ValueError(f"without: only the netlogo semantics has NetLogo rules to switch off, got {semantics!r}")


def agent_seeds(seed, agents: int) -> np.ndarray:
    """[A] int64: seed + a for one number, else the seeds given (one per agent)."""
    seeds = seed + np.arange(agents, dtype=np.int64) if np.ndim(seed) == 0 else np.asarray(seed, np.int64)
    if seeds.shape != (agents,):
        raise ValueError(f"seed: one number, or one per agent ({agents}), got {seeds.shape[0]}")
    return seeds


def build_network(
    circuit: Circuit, params: dict, seeds: np.ndarray, semantics: str, order: str, without=(), by_receiver=True
) -> Network:
    """The Network of `circuit` for agents with these per-agent columns (services.params) and seeds;
    `by_receiver=False` keeps the netlogo turns one by one where they could run by receiver (the
    same results: for tests and benchmarks)."""
    c, agents = circuit, len(seeds)
    n_neurons, n_inputs, n_synapses = len(c.neuron_names), len(c.inputs), len(c.synapses)
    if n_synapses >= 1 << SYN_BITS:
        raise ValueError(f"at most {1 << SYN_BITS} synapses, got {n_synapses}")
    syn = np.array(
        [[s.pre, s.post, s.delay, INHIBITORY * s.inhibitory | PLASTIC * s.plastic] for s in c.synapses],
        dtype=np.int64,
    ).reshape(n_synapses, 4)
    _, offset = stdp_table(c.neuron_types)
    npar = np.array([[getattr(t, name) for name in NEURON_COLUMNS] + [offset] for t in c.neuron_types], np.float64)
    inpar = np.array(
        [[i.pulses, np.nan if i.at_start is None else i.at_start] for i in c.inputs], dtype=np.float64
    ).reshape(n_inputs, 2)
    stdp, group, profile = learning_tables(c, params, agents)
    if semantics == "netlogo":  # each neuron's outgoing synapses, for its turn
        pre, post = syn[: n_synapses - n_inputs, PRE], syn[: n_synapses - n_inputs, POST]
        out_syn = np.argsort(pre, kind="stable").astype(np.uint64)
        out_start = np.searchsorted(pre[out_syn], np.arange(n_neurons + 1)).astype(np.uint64)
        in_syn = np.lexsort((pre, post)).astype(np.uint64)  # stable: file order within one pre
        in_start = np.searchsorted(post[in_syn], np.arange(n_neurons + 1)).astype(np.uint64)
        order_key = mix(seeds.view(np.uint64))  # once here rather than in every tick
        order_jump = lcg_jumps(n_neurons)  # the same
        rules = SHUFFLE * (order == "random") | STREAM * (order == "netlogo-stream")
        rules |= sum(f for k, f in NETLOGO_RULES.items() if k not in without)
        sent_now = bool(rules & COUNT_FROM_SEND) and bool((syn[: n_synapses - n_inputs, DELAY] <= 1).any())
        few_in = np.bincount(post, minlength=1).max() <= 64  # a bit each
        packed = order in ("file", "random") and n_neurons <= 16  # the places of the turns in a word
        if by_receiver and agents >= BY_RECEIVER_FROM and few_in and not sent_now and packed:
            rules |= BY_RECEIVER
    else:
        out_start, out_syn = np.zeros(n_neurons + 1, np.uint64), np.zeros(0, np.uint64)
        in_start, in_syn = out_start, out_syn
        order_key, order_jump, rules = np.zeros(agents, np.uint64), np.zeros((2, 0), np.uint64), 0
    stream_order = source_order(c) if order == "netlogo-stream" else np.zeros(0, np.uint64)
    order_fields = (out_start, out_syn, in_start, in_syn, order_key, order_jump, rules, stream_order)
    learns = np.isin(np.arange(n_neurons), list(c.learning_neurons))
    return Network(syn, npar, inpar, stdp, group, profile, learns, *order_fields)


def lcg_jumps(steps: int) -> np.ndarray:
    """[2, steps] uint64: the netlogo order's LCG (LCG_MUL, LCG_ADD) k steps on from r is
    r * jumps[0, k] + jumps[1, k], so an order's draws are independent multiplies, not a chain."""
    jumps, mul, add = np.zeros((2, steps), np.uint64), 1, 0
    for k in range(steps):
        jumps[:, k] = mul, add
        mul, add = mul * int(LCG_MUL) % 2**64, (add * int(LCG_MUL) + int(LCG_ADD)) % 2**64
    return jumps


def new_state(circuit: Circuit, agents: int, stream: bool = False) -> State:
    """The State arrays of `agents` agents of `circuit`, not yet set (Engine.reset sets them);
    `stream`: with a row of NetLogo's stream per agent (order netlogo-stream)."""
    N, S, nodes = len(circuit.neuron_names), len(circuit.synapses), len(circuit.node_names)
    max_delay = max((s.delay for s in circuit.synapses), default=1)
    ring_len = 1 << int(max_delay).bit_length()  # > max delay, a power of two for masking
    return State(
        clock=np.zeros(2, dtype=np.int64),
        v=np.empty((N, agents)),
        w=np.empty((S, agents)),
        counters=np.empty((3, nodes, agents), dtype=np.int32),
        last_spike=np.empty((N, agents), dtype=np.int64),
        hist=np.zeros((agents, N, HISTORY + 1), dtype=np.int64),
        ring=np.empty((ring_len, S, agents), dtype=np.uint8),
        spiked=np.zeros((nodes, agents), dtype=np.uint8),
        stream=np.zeros((agents, STREAM_TURNS + N if stream else 0), dtype=np.uint32),
    )


LCG_MUL, LCG_ADD = np.uint64(6364136223846793005), np.uint64(1442695040888963407)  # the netlogo order's LCG


@njit(cache=True, inline="always")
def mix(x):
    """splitmix64 of a uint64: the netlogo order is a pure function of (agent seed, tick)."""
    z = x + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _variant(circuit: Circuit, values: dict) -> Circuit:
    """The circuit with one agent's learning values: initial weight first (the w_max check is on it)."""
    if "initial_weight" in values:
        w = values["initial_weight"]
        circuit = dataclasses.replace(
            circuit, synapses=tuple(dataclasses.replace(s, weight=w) if s.plastic else s for s in circuit.synapses)
        )
    fields = {k: v for k, v in values.items() if k in LEARNING_FIELDS}
    return circuit.with_learning_params(**fields)  # with none, the initial weight's range is checked


def learning_tables(circuit: Circuit, params: dict, agents: int) -> tuple:
    """(stdp [groups, profiles, LO, HI, W(dt)...], group [A], profile [N]): one group per distinct
    row of the learning columns; a profile per (neuron type, learns or not), as the columns set the
    learning neurons only."""
    names = [k for k in params if k in LEARNING_FIELDS or k == "initial_weight"]
    rows = np.column_stack([params[k] for k in names]) if names else np.zeros((agents, 0))
    settings, group = np.unique(rows, axis=0, return_inverse=True)
    learning = circuit.learning_neurons
    keys = [(t, n in learning) for n, t in enumerate(circuit.neuron_types)]
    kinds = list(dict.fromkeys(keys))
    profile = np.array([kinds.index(k) for k in keys], dtype=np.int64)
    first = [keys.index(k) for k in kinds]  # a neuron of each profile
    tables = []
    for g, row in enumerate(settings):
        values = {k: float(v) for k, v in zip(names, row)}
        try:
            neuron_types = _variant(circuit, values).neuron_types
        except ValueError as e:  # the circuit's fault names its file: this one is the values'
            agent = int(np.flatnonzero(group == g)[0])
            given = ", ".join(f"{k} {v:g}" for k, v in values.items())
            problem = str(e).removeprefix(f"{circuit.source}: ")
            raise AgentValueError(
                f"the values of agent {agent} ({given}) do not fit circuit {circuit.name!r}: {problem}", agent
            ) from None
        table, _ = stdp_table(neuron_types)
        tables.append(
            np.column_stack(
                [[neuron_types[n].w_min for n in first], [neuron_types[n].w_max for n in first], table[first]]
            )
        )
    return np.ascontiguousarray(np.stack(tables)), group.reshape(agents).astype(np.int64), profile


def initial_weights(circuit: Circuit, params: dict, agents: int) -> np.ndarray:
    """[A, synapses]: the circuit's weights, the plastic ones at each agent's initial weight, those of
    the input neurons a sensor feeds times each agent's input gain."""
    w = np.tile(np.array([s.weight for s in circuit.synapses], dtype=np.float64), (agents, 1))
    if "initial_weight" in params:
        plastic = circuit.plastic_synapses
        w[:, plastic] = params["initial_weight"][:, None]
    if "input_gain" in params:
        n_net = len(circuit.synapses) - len(circuit.inputs)  # an input neuron's synapse: n_net + its index
        sensed = [n_net + k for k in circuit.sensors.values()]
        w[:, sensed] *= params["input_gain"][:, None]
    return w
