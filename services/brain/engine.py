"""The spiking-network engine: A agents of one circuit stepped together, one tick per call.

State is a struct of arrays with an agent axis (no per-neuron objects); inside, the agent axis is
last so that each phase is one vectorised loop across agents, and the public views `v`, `w` and
`spiked` are [A, ...]. One tick runs five named phases in a fixed order (docs/tick.md):

  1. feed     an idle input neuron latches a sensor value x: it will spike floor(x) + 1 ticks
              on, counting this one (so at t + floor(x)); a busy one ignores the value
  2. inputs   input neurons count; one whose count reaches its latency spikes, and its pulse
              is scheduled on its synapse (delay 0: delivered in this same tick)
  3. deliver  pulses due this tick reach their post neuron: potential change if OPEN,
              STDP depression and history for plastic synapses
  4. fire     each neuron: refractory clamp, or fire at threshold (STDP potentiation), or decay
  5. emit     every synapse of a node that spiked schedules a pulse at t + delay

That is the "phased" semantics. The "netlogo" semantics (`Engine(..., semantics="netlogo")`)
reproduces the original SpikingLab NetLogo engine instead (docs/tick.md): input neurons first,
then every neuron in its turn, in a seeded random order per agent and tick (or file order), each
running its state machine and then at once the pulse queues of its own outgoing synapses.

The same circuit, feeds and seeds give the same spikes and weights, bit for bit, whether agents
are stepped alone or together: the only randomness (the netlogo order) is a pure function of
(agent seed, tick). Nothing here knows Zenoh.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import get_num_threads, njit, prange

from services.kernels import Kernel
from services.params import LEARNING_FIELDS, PARALLEL_FROM, agent_columns
from services.snapshots import copy_into

from .circuit import Circuit
from .stdp import stdp_table

HISTORY = 30  # arrivals a neuron remembers since its last spike (oldest dropped)
NEVER = -(2**62)  # last-spike tick of a neuron that has not fired yet
SYN_BITS = 16  # a history entry packs (arrival tick << SYN_BITS) | synapse index
SYN_MASK = (1 << SYN_BITS) - 1
SEMANTICS = ("phased", "netlogo")
DEFAULT_SEMANTICS = "netlogo"  # the original's engine: the only one that learns in every setting (docs/results.md)
ORDERS = ("random", "file")  # netlogo: neurons per tick in a seeded random order, or in file order
# netlogo rules, each of which can be switched off alone to measure what it does (docs/results.md)
SHUFFLE, COUNT_FROM_SEND, REOPEN_IN_TURN, DT0_AGAIN = 1, 2, 4, 8
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
# node state planes [3, nodes, A] (int32): for neurons ...
REFR_LEFT, HIST_LEN, REFRACTORY = 0, 1, 2  # REFRACTORY: netlogo's state flag (its counter may be <= 0)
# ... and for input neurons (the nodes after the neurons): ticks counted, pulses left, latency
COUNT, LEFT, LATENCY = 0, 1, 2
# inpar columns: per input neuron
PULSES, AT_START = 0, 1
# clock: [tick, training]
TICK, TRAINING = 0, 1


@njit(cache=True, inline="always")
def _learn(w, s, a, post, dt, npar, lrn):
    """STDP: w[s, a] += W(dt) from the table of the post neuron and agent, clipped to [w_min, w_max]."""
    stdp, group, profile = lrn
    k = dt + int(npar[post, STDP_OFFSET])
    if 0 <= k < stdp.shape[2] - TABLE:
        g, p = group[a], profile[post]
        w[s, a] = min(max(w[s, a] + stdp[g, p, TABLE + k], stdp[g, p, LO]), stdp[g, p, HI])


# Each phase is a loop across agents lo..hi with unsigned indices (numba then emits no
# negative-index checks), so the loops compile to vector code.


@njit(cache=True, inline="always")
def _feed_and_inputs(lo, hi, t, feed, inpar, syn, n_neurons, state, ring, spiked):
    """Phases 1 (feed) and 2 (inputs), in one loop: each input neuron is independent."""
    mask = ring.shape[0] - 1
    n_net = syn.shape[0] - feed.shape[1]  # the input neurons' synapses come last, one each
    for i in range(feed.shape[1]):
        node, s = n_neurons + i, n_net + i
        pulses = np.int32(inpar[i, PULSES])
        start = t == 0 and not math.isnan(inpar[i, AT_START])  # the circuit's own feed at tick 0
        slot = (t + syn[s, DELAY]) & mask  # delay 0: delivered in this tick's phase 3
        # Feeds arrive at random, so this loop computes every field and selects (no branches).
        for a in range(lo, hi):
            # 1. feed: an idle input neuron latches x >= 0 (NaN: nothing fed); busy ones ignore it
            x = inpar[i, AT_START] if start else feed[a, i]
            left = state[LEFT, node, a]
            take = left == 0 and x >= 0.0 and x < 1e9  # NaN and inf fail the tests
            latency = np.int32(x if take else 0.0) + np.int32(1)  # floor(x) + 1; int() is floor() for x >= 0
            lat = latency if take else state[LATENCY, node, a]
            count = np.int32(0) if take else state[COUNT, node, a]
            left = pulses if take else left
            # 2. inputs: count this tick; a pulse when the count reaches the latency
            count += left > 0
            fired = left > 0 and count == lat
            state[LATENCY, node, a] = lat
            state[COUNT, node, a] = np.int32(0) if fired else count
            state[LEFT, node, a] = left - fired
            spiked[node, a] = fired
            ring[slot, s, a] = fired  # empty: delivered and cleared a ring length ago


@njit(cache=True, inline="always")
def _deliver(lo, hi, t, training, syn, npar, lrn, v, w, state, last_spike, hist, ring):
    """Phase 3: pulses due now. A REFRACTORY post ignores them (w * r * open is exactly 0 or w),
    but they still count for learning: depression now, and a place in the post's history."""
    slot = t & (ring.shape[0] - 1)
    for s in range(syn.shape[0]):
        post = syn[s, POST]
        if syn[s, FLAGS] & INHIBITORY:
            floor = npar[post, FLOOR]
            for a in range(lo, hi):  # v >= floor always holds, so max() is exact when dv = 0
                dv = w[s, a] * ring[slot, s, a] * (state[REFR_LEFT, post, a] == 0)
                v[post, a] = max(v[post, a] - dv, floor)
        else:
            for a in range(lo, hi):
                v[post, a] += w[s, a] * ring[slot, s, a] * (state[REFR_LEFT, post, a] == 0)
        if syn[s, FLAGS] & PLASTIC:
            for a in range(lo, hi):
                if ring[slot, s, a] == 0:
                    continue
                last = last_spike[post, a]
                if training and last != NEVER:  # once per pulse, against the latest post spike
                    _learn(w, s, a, post, t - last, npar, lrn)
                n = state[HIST_LEN, post, a]
                if n == HISTORY:  # drop the oldest
                    for h in range(HISTORY - 1):
                        hist[a, post, h] = hist[a, post, h + 1]
                    n -= 1
                hist[a, post, n] = (t << SYN_BITS) | s
                state[HIST_LEN, post, a] = n + 1
        for a in range(lo, hi):
            ring[slot, s, a] = 0


@njit(cache=True, inline="always")
def _fire(lo, hi, t, training, npar, lrn, v, w, state, last_spike, hist, spiked):
    """Phase 4: refractory clamp, fire at threshold (STDP potentiation), or decay toward rest."""
    for n in range(v.shape[0]):
        threshold, rest, decay = npar[n, THRESHOLD], npar[n, REST], npar[n, DECAY]
        refr_v, period = npar[n, REFR_V], np.int32(npar[n, REFR_PERIOD])
        for a in range(lo, hi):
            refractory = state[REFR_LEFT, n, a] > 0
            fire = not refractory and v[n, a] >= threshold
            decayed = v[n, a] + (rest - v[n, a]) * decay  # never overshoots rest: decay < 1
            v[n, a] = refr_v if refractory or fire else decayed
            state[REFR_LEFT, n, a] = period if fire else state[REFR_LEFT, n, a] - refractory
            last_spike[n, a] = t if fire else last_spike[n, a]
            spiked[n, a] = fire
        for a in range(lo, hi):
            if spiked[n, a] and state[HIST_LEN, n, a] > 0:
                if training:  # every remembered arrival is paired with this spike
                    for h in range(state[HIST_LEN, n, a]):
                        entry = hist[a, n, h]
                        _learn(w, entry & SYN_MASK, a, n, (entry >> SYN_BITS) - t, npar, lrn)
                state[HIST_LEN, n, a] = 0


@njit(cache=True, inline="always")
def _emit(lo, hi, t, syn, n_inputs, ring, spiked):
    """Phase 5: every synapse of a neuron that spiked schedules a pulse at t + delay (>= 1). That
    slot is empty (delivered and cleared a ring length ago), so a plain copy needs no branch.
    Input neurons sent theirs in phase 2."""
    mask = ring.shape[0] - 1  # ring length is a power of two
    for s in range(syn.shape[0] - n_inputs):
        slot, pre = (t + syn[s, DELAY]) & mask, syn[s, PRE]
        for a in range(lo, hi):
            ring[slot, s, a] = spiked[pre, a]


@njit(cache=True, inline="always")
def _step_range(lo, hi, feed, clock, syn, npar, lrn, inpar, v, w, state, last_spike, hist, ring, spiked):
    """One tick for agents lo..hi-1 (unsigned). Arrays have the agent axis last, so each phase is
    a loop across agents; only events (plastic arrivals, spikes of learning neurons) branch."""
    t = clock[TICK]
    training = clock[TRAINING] != 0
    _feed_and_inputs(lo, hi, t, feed, inpar, syn, v.shape[0], state, ring, spiked)
    _deliver(lo, hi, t, training, syn, npar, lrn, v, w, state, last_spike, hist, ring)
    _fire(lo, hi, t, training, npar, lrn, v, w, state, last_spike, hist, spiked)
    _emit(lo, hi, t, syn, feed.shape[1], ring, spiked)


@njit(cache=True)
def _step_serial(
    feed,
    clock,
    syn,
    npar,
    lrn,
    inpar,
    v,
    w,
    state,
    last_spike,
    hist,
    ring,
    spiked,
    out_start,
    out_syn,
    order_key,
    rules,
):
    _step_range(
        np.uint64(0),
        np.uint64(v.shape[1]),
        feed,
        clock,
        syn,
        npar,
        lrn,
        inpar,
        v,
        w,
        state,
        last_spike,
        hist,
        ring,
        spiked,
    )
    clock[TICK] += 1


@njit(cache=True, parallel=True)
def _step_parallel(
    feed,
    clock,
    syn,
    npar,
    lrn,
    inpar,
    v,
    w,
    state,
    last_spike,
    hist,
    ring,
    spiked,
    out_start,
    out_syn,
    order_key,
    rules,
    chunks,
):
    agents = v.shape[1]
    for c in prange(chunks):  # one contiguous block of agents per thread
        lo, hi = np.uint64(c * agents // chunks), np.uint64((c + 1) * agents // chunks)
        _step_range(lo, hi, feed, clock, syn, npar, lrn, inpar, v, w, state, last_spike, hist, ring, spiked)
    clock[TICK] += 1


# --- netlogo semantics: the original SpikingLab engine, turn by turn ------------------------------
# Per tick: input neurons (each pulse reaches its target at once), then every neuron in its turn:
# its state machine, then at once the pulse queues of its outgoing synapses. A pulse sent at t on
# a synapse of delay d is counted down from d in the sending tick and delivered at 0, so it
# arrives at t + d - 1 in the sender's turn: before or after the receiver's own turn in that
# tick, depending on the order (effective delay d - 1 or d).


@njit(cache=True, inline="always")
def _mix(x):
    """splitmix64 of a uint64: the netlogo order is a pure function of (agent seed, tick)."""
    z = x + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, inline="always")
def _netlogo_receive(a, t, s, training, rules, syn, npar, lrn, v, w, state, last_spike, hist):
    """NetLogo receive-pulse: potential change unless REFRACTORY; a plastic arrival in training is
    remembered and the STDP rule runs over the whole history since the post's last spike.

    Every remembered arrival came at or after that spike (the history is cleared when it fires),
    and each was depressed once, at its own arrival. So of the whole history only two kinds of
    entry change w: those at dt = 0 (arrived in the spike's tick, after the spike: they
    potentiate again at every arrival, NetLogo's dt = 0 quirk), which are a prefix, and the new
    arrival itself (depressed once if dt > 0). Running just those, in history order, gives the
    same weights as NetLogo's full pass."""
    post = syn[s, POST]
    if state[REFRACTORY, post, a] == 0:
        if syn[s, FLAGS] & INHIBITORY:
            v[post, a] = max(v[post, a] - w[s, a], npar[post, FLOOR])
        else:
            v[post, a] += w[s, a]
    if training and syn[s, FLAGS] & PLASTIC:
        n = state[HIST_LEN, post, a]
        if n > HISTORY:  # NetLogo drops the oldest when it holds more than 30, then appends: up to 31
            for h in range(n - 1):
                hist[a, post, h] = hist[a, post, h + 1]
            n -= 1
        hist[a, post, n] = (t << SYN_BITS) | s
        state[HIST_LEN, post, a] = n + 1
        last = last_spike[post, a]
        if rules & DT0_AGAIN:
            for h in range(n + 1):  # the dt = 0 prefix (the new arrival too, when it is at dt = 0)
                entry = hist[a, post, h]
                if (entry >> SYN_BITS) != last:
                    break
                _learn(w, entry & SYN_MASK, a, post, 0, npar, lrn)
            if t > last:  # the new arrival's one depression
                _learn(w, s, a, post, t - last, npar, lrn)
        else:  # the new arrival alone: potentiation at dt = 0, else its one depression
            _learn(w, s, a, post, t - last, npar, lrn)


@njit(cache=True, inline="always")
def _netlogo_range(
    lo,
    hi,
    feed,
    clock,
    syn,
    npar,
    lrn,
    inpar,
    v,
    w,
    state,
    last_spike,
    hist,
    ring,
    spiked,
    out_start,
    out_syn,
    order_key,
    rules,
):
    """One NetLogo tick for agents lo..hi-1: each agent is a sequence of turns (no vector loop)."""
    t = clock[TICK]
    training = clock[TRAINING] != 0
    n_neurons = v.shape[0]
    _feed_and_inputs(lo, hi, t, feed, inpar, syn, n_neurons, state, ring, spiked)  # input pulses: slot t
    mask = ring.shape[0] - 1
    now = np.uint64(t & mask)
    n_net = syn.shape[0] - feed.shape[1]
    order = np.empty(n_neurons, np.uint64)  # unsigned indices: no negative-index checks
    send = np.int64(1) if rules & COUNT_FROM_SEND else np.int64(0)  # count-down ticks used in the sending tick
    for a in range(lo, hi):
        if not rules & REOPEN_IN_TURN:  # refractory periods that ended in the last tick end now
            for n in range(n_neurons):
                if state[REFRACTORY, n, a] and state[REFR_LEFT, n, a] <= 0:
                    state[REFRACTORY, n, a] = 0
        for s in range(n_net, syn.shape[0]):  # input neurons: straight to their target, not plastic
            if ring[now, s, a]:
                ring[now, s, a] = 0
                post = syn[s, POST]
                if state[REFRACTORY, post, a] == 0:
                    v[post, a] += w[s, a]
        for n in range(n_neurons):
            order[n] = np.uint64(n)
        if rules & SHUFFLE:  # Fisher-Yates: a hashed (seed, tick) start, then LCG steps, j by multiply-shift
            r = _mix(order_key[a] + np.uint64(t))
            for i in range(n_neurons - 1, 0, -1):
                r = r * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
                j = ((r >> np.uint64(32)) * np.uint64(i + 1)) >> np.uint64(32)
                order[i], order[j] = order[j], order[i]
        for k in range(n_neurons):
            n = order[k]
            spiked[n, a] = 0
            if state[REFRACTORY, n, a] == 0:
                if v[n, a] != npar[n, REST]:
                    if v[n, a] >= npar[n, THRESHOLD]:  # fire: potentiation over the history, pulses out
                        last_spike[n, a] = t
                        for h in range(state[HIST_LEN, n, a]):
                            entry = hist[a, n, h]
                            _learn(w, entry & SYN_MASK, a, n, (entry >> SYN_BITS) - t, npar, lrn)
                        state[HIST_LEN, n, a] = 0
                        for q in range(out_start[n], out_start[n + 1]):
                            s = out_syn[q]
                            ring[np.uint64((t + syn[s, DELAY] - send) & mask), s, a] = 1
                        state[REFRACTORY, n, a] = 1
                        state[REFR_LEFT, n, a] = np.int32(npar[n, REFR_PERIOD])
                        spiked[n, a] = 1
                    else:
                        v[n, a] += (npar[n, REST] - v[n, a]) * npar[n, DECAY]
            else:  # one tick of the refractory period, held at the refractory potential
                state[REFR_LEFT, n, a] -= 1
                v[n, a] = npar[n, REFR_V]
                if state[REFR_LEFT, n, a] <= 0 and rules & REOPEN_IN_TURN:
                    state[REFRACTORY, n, a] = 0  # open again: later arrivals in this tick count
            for q in range(out_start[n], out_start[n + 1]):  # its synapses' pulses due now
                s = out_syn[q]
                if ring[now, s, a]:
                    ring[now, s, a] = 0
                    _netlogo_receive(a, t, s, training, rules, syn, npar, lrn, v, w, state, last_spike, hist)


@njit(cache=True)
def _netlogo_serial(
    feed,
    clock,
    syn,
    npar,
    lrn,
    inpar,
    v,
    w,
    state,
    last_spike,
    hist,
    ring,
    spiked,
    out_start,
    out_syn,
    order_key,
    rules,
):
    _netlogo_range(
        np.uint64(0),
        np.uint64(v.shape[1]),
        feed,
        clock,
        syn,
        npar,
        lrn,
        inpar,
        v,
        w,
        state,
        last_spike,
        hist,
        ring,
        spiked,
        out_start,
        out_syn,
        order_key,
        rules,
    )
    clock[TICK] += 1


@njit(cache=True, parallel=True)
def _netlogo_parallel(
    feed,
    clock,
    syn,
    npar,
    lrn,
    inpar,
    v,
    w,
    state,
    last_spike,
    hist,
    ring,
    spiked,
    out_start,
    out_syn,
    order_key,
    rules,
    chunks,
):
    agents = v.shape[1]
    for c in prange(chunks):
        lo, hi = np.uint64(c * agents // chunks), np.uint64((c + 1) * agents // chunks)
        _netlogo_range(
            lo,
            hi,
            feed,
            clock,
            syn,
            npar,
            lrn,
            inpar,
            v,
            w,
            state,
            last_spike,
            hist,
            ring,
            spiked,
            out_start,
            out_syn,
            order_key,
            rules,
        )
    clock[TICK] += 1


@njit(cache=True, inline="always")
def serial_tick(
    netlogo,
    feed,
    clock,
    syn,
    npar,
    lrn,
    inpar,
    v,
    w,
    state,
    last_spike,
    hist,
    ring,
    spiked,
    out_start,
    out_syn,
    order_key,
    rules,
):
    """One tick of either semantics on one thread, for compiled loops of many ticks (Engine.run,
    services.loop's fused loop); the arguments after the feed are Engine.serial_args."""
    if netlogo:
        _netlogo_serial(
            feed,
            clock,
            syn,
            npar,
            lrn,
            inpar,
            v,
            w,
            state,
            last_spike,
            hist,
            ring,
            spiked,
            out_start,
            out_syn,
            order_key,
            rules,
        )
    else:
        _step_serial(
            feed,
            clock,
            syn,
            npar,
            lrn,
            inpar,
            v,
            w,
            state,
            last_spike,
            hist,
            ring,
            spiked,
            out_start,
            out_syn,
            order_key,
            rules,
        )


@njit(cache=True)
def _run_serial(
    feeds,
    netlogo,
    out,
    clock,
    syn,
    npar,
    lrn,
    inpar,
    v,
    w,
    state,
    last_spike,
    hist,
    ring,
    spiked,
    out_start,
    out_syn,
    order_key,
    rules,
):
    """Engine.run's ticks in one call: feeds [T, A, inputs] -> out [T, A, nodes]."""
    for k in range(feeds.shape[0]):
        serial_tick(
            netlogo,
            feeds[k],
            clock,
            syn,
            npar,
            lrn,
            inpar,
            v,
            w,
            state,
            last_spike,
            hist,
            ring,
            spiked,
            out_start,
            out_syn,
            order_key,
            rules,
        )
        for a in range(spiked.shape[1]):
            for n in range(spiked.shape[0]):
                out[k, a, n] = spiked[n, a] != 0


class Engine:
    """A agents of one circuit (same synapses, independent potentials, pulses and weights).

    Per tick: call `step(feed)` with the sensor values (shape [A, inputs], NaN = nothing fed; or
    no argument when nothing is fed), then read `spiked` ([A, nodes]: neurons then input
    neurons), `v` and `w`.

    `semantics`: "phased" (five phases, a delay of d is exactly d) or "netlogo" (the original
    engine's turns, docs/tick.md). With "netlogo", `order` is "random" (agent a's order at tick t
    is drawn from seed + a and t) or "file" (circuit file order every tick), and `without` names
    NetLogo rules to switch off one at a time (NETLOGO_RULES; for ablations, not for use). `seed`
    may also be one seed per agent (an array [A]; agents taken from a larger population).

    `params`: per-agent parameters (services.params, the brain's columns: A+, A-, tau+/-, w_max,
    initial weight, input gain), each a number or one value per agent; agents with the same
    values share one STDP table.
    """

    def __init__(
        self,
        circuit: Circuit,
        agents: int = 1,
        training: bool = True,
        semantics: str = DEFAULT_SEMANTICS,
        order: str = "random",
        seed=0,
        without: tuple[str, ...] = (),
        params=None,
    ):
        if agents < 1:
            raise ValueError(f"agents must be >= 1, got {agents}")
        if semantics not in SEMANTICS:
            raise ValueError(f"semantics must be one of {', '.join(SEMANTICS)}, got {semantics!r}")
        if order not in ORDERS:
            raise ValueError(f"order must be one of {', '.join(ORDERS)}, got {order!r}")
        self.circuit = circuit
        self.agents = agents
        unknown = sorted(set(without) - set(NETLOGO_RULES))
        if unknown or (without and semantics != "netlogo"):
            raise ValueError(
                f"without: NetLogo rules are {', '.join(NETLOGO_RULES)} (netlogo semantics only), "
                f"got {', '.join(without)}"
            )
        self.semantics, self.order, self.without = semantics, order, tuple(without)
        self.seeds = seed + np.arange(agents, dtype=np.int64) if np.ndim(seed) == 0 else np.asarray(seed, np.int64)
        if self.seeds.shape != (agents,):
            raise ValueError(f"seed: one number, or one per agent ({agents}), got {self.seeds.shape[0]}")
        c = circuit
        self.n_neurons, self.n_inputs, self.n_synapses = len(c.neuron_names), len(c.inputs), len(c.synapses)
        self.syn = np.array(
            [[s.pre, s.post, s.delay, INHIBITORY * s.inhibitory | PLASTIC * s.plastic] for s in c.synapses],
            dtype=np.int64,
        ).reshape(self.n_synapses, 4)
        _, offset = stdp_table(c.neuron_types)
        self.npar = np.array(
            [[getattr(t, name) for name in NEURON_COLUMNS] + [offset] for t in c.neuron_types], dtype=np.float64
        )
        self.inpar = np.array(
            [[i.pulses, np.nan if i.at_start is None else i.at_start] for i in c.inputs], dtype=np.float64
        ).reshape(self.n_inputs, 2)
        self.params = agent_columns(agents, params, "brain")
        self.lrn = learning_tables(c, self.params, agents)
        self.initial_weights = initial_weights(c, self.params, agents)
        max_delay = max((sy.delay for sy in c.synapses), default=1)
        ring_len = 1 << int(max_delay).bit_length()  # > max delay, a power of two for masking
        if self.n_synapses >= 1 << SYN_BITS:
            raise ValueError(f"at most {1 << SYN_BITS} synapses, got {self.n_synapses}")
        A, N, I, S = agents, self.n_neurons, self.n_inputs, self.n_synapses
        # Internal arrays keep the agent axis last (each phase is a loop across agents); the
        # public v, w and spiked are [A, ...] views of them.
        self.no_feed = np.full((A, I), np.nan)  # read-only: the kernel never writes a feed
        self.clock = np.zeros(2, dtype=np.int64)
        self._v = np.empty((N, A))
        self._w = np.empty((S, A))
        self.state = np.empty((3, N + I, A), dtype=np.int32)
        self.last_spike = np.empty((N, A), dtype=np.int64)
        self.hist = np.zeros((A, N, HISTORY + 1), dtype=np.int64)  # per event: agent-major (netlogo keeps 31)
        self.ring = np.empty((ring_len, S, A), dtype=np.uint8)
        self._spiked = np.zeros((N + I, A), dtype=np.uint8)
        self.v = self._v.T  # [A, neurons] membrane potentials
        self.w = self._w.T  # [A, synapses] weights
        self.spiked = self._spiked.view(np.bool_).T  # [A, nodes] who spiked in the last tick
        self._args = (
            self.clock,
            self.syn,
            self.npar,
            self.lrn,
            self.inpar,
            self._v,
            self._w,
            self.state,
            self.last_spike,
            self.hist,
            self.ring,
            self._spiked,
        )
        serial, parallel = _step_serial, _step_parallel
        if semantics == "netlogo":  # each neuron's outgoing synapses, for its turn
            pre = self.syn[: S - I, PRE]
            self.out_syn = np.argsort(pre, kind="stable").astype(np.uint64)
            self.out_start = np.searchsorted(pre[self.out_syn], np.arange(N + 1)).astype(np.uint64)
            # agent a's order key: the hash of seed + a, once here rather than in every tick
            self.order_key = _mix(self.seeds.view(np.uint64))
            rules = SHUFFLE * (order == "random") | sum(f for k, f in NETLOGO_RULES.items() if k not in without)
            self._args += (self.out_start, self.out_syn, self.order_key, rules)
            serial, parallel = _netlogo_serial, _netlogo_parallel
        else:  # the same arguments for both (a fused loop calls either): the phased engine ignores them
            self._args += (np.zeros(N + 1, np.uint64), np.zeros(0, np.uint64), np.zeros(A, np.uint64), 0)
        self.serial_args = self._args  # a serial tick's arguments after the feed (services.loop fuses it)
        if agents >= PARALLEL_FROM:
            self._call, self._args = Kernel(parallel), self._args + (get_num_threads(),)
        else:
            self._call = Kernel(serial)
        self.training = training
        self.reset()

    def reset(self) -> None:
        """Back to tick 0: potentials at rest, initial weights, nothing in flight."""
        self.clock[TICK] = 0
        N = self.n_neurons
        self.v[:] = self.npar[:N, REST]
        self.w[:] = self.initial_weights
        self.state[:] = 0
        self.last_spike[:] = 0 if self.semantics == "netlogo" else NEVER  # NetLogo's variables start at 0
        self.hist[:] = 0
        self.ring[:] = 0
        self._spiked[:] = 0

    @property
    def tick(self) -> int:
        """The tick the next step() will run."""
        return int(self.clock[TICK])

    @property
    def training(self) -> bool:
        return bool(self.clock[TRAINING])

    @training.setter
    def training(self, on: bool) -> None:
        self.clock[TRAINING] = 1 if on else 0

    def step(self, feed: np.ndarray | None = None) -> np.ndarray:
        """Run one tick with `feed` ([A, inputs] values, NaN = nothing fed; None: nothing at all).

        Returns `spiked`, a bool view [A, nodes] that the next step overwrites.
        """
        if feed is None:
            feed = self.no_feed
        elif (
            type(feed) is not np.ndarray
            or feed.dtype != np.float64
            or feed.shape != self.no_feed.shape
            or not feed.flags.c_contiguous
            or not feed.flags.writeable
        ):
            feed = self._checked_feed(feed)
        self._call(feed, *self._args)
        return self.spiked

    def _checked_feed(self, feed) -> np.ndarray:
        feed = np.array(feed, dtype=np.float64, order="C")  # a copy: writeable, as the kernel's type says
        if feed.shape != self.no_feed.shape:
            raise ValueError(f"feed must have shape {self.no_feed.shape} (agents, inputs), got {feed.shape}")
        return feed

    def snapshot(self) -> dict[str, np.ndarray]:
        """Copies of everything the next ticks depend on: clock, potentials, weights, counters,
        histories and pulses in flight (whole-run checkpoints, services/snapshots.py)."""
        return {name: array.copy() for name, array in self._state_arrays().items()}

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Back to a snapshot() of an engine of the same circuit and agents, copied in place."""
        copy_into(self._state_arrays(), arrays, "engine snapshot")

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return {
            "clock": self.clock,
            "v": self._v,
            "w": self._w,
            "state": self.state,
            "last_spike": self.last_spike,
            "hist": self.hist,
            "ring": self.ring,
            "spiked": self._spiked,
        }

    def get_weights(self) -> np.ndarray:
        """A copy of all synapse weights, [A, synapses] (checkpoints)."""
        return self.w.copy()

    def set_weights(self, weights) -> None:
        """Replace all weights ([synapses] for every agent, or [A, synapses]); plastic ones must be in range."""
        weights = (
            np.broadcast_to(np.asarray(weights, dtype=np.float64), self.w.shape)
            if np.ndim(weights) == 1
            else np.asarray(weights, dtype=np.float64)
        )
        if weights.shape != self.w.shape:
            raise ValueError(f"weights must have shape {self.w.shape} or ({self.n_synapses},), got {weights.shape}")
        if not np.all(np.isfinite(weights)) or np.any(weights <= 0):
            raise ValueError("weights must be finite and > 0")
        stdp, group, profile = self.lrn
        post = self.syn[:, POST]
        plastic = (self.syn[:, FLAGS] & PLASTIC) != 0
        limits = stdp[group[:, None], profile[post][None, :]]  # [A, S, LO..HI]
        lo, hi = limits[..., LO], limits[..., HI]
        bad = plastic & ((weights < lo) | (weights > hi))
        if bad.any():
            a, k = (int(i[0]) for i in np.nonzero(bad))
            raise ValueError(
                f"weight of plastic synapse {self.circuit.synapse_label(k)} of agent {a} outside "
                f"[{lo[a, k]}, {hi[a, k]}]"
            )
        self.w[:] = weights

    def run(self, feeds: np.ndarray) -> np.ndarray:
        """Step len(feeds) ticks with feeds [T, A, inputs]; returns the spikes [T, A, nodes]. For
        the populations stepped on one thread, all T ticks are one compiled call (no Python
        between ticks: a per-tick step() is bound by passing its 17 arrays into the kernel)."""
        feeds = np.ascontiguousarray(feeds, dtype=np.float64)  # only read by the kernels
        if feeds.ndim != 3 or feeds.shape[1:] != self.no_feed.shape:
            raise ValueError(f"feeds must have shape (ticks, {self.agents}, {self.n_inputs}), got {feeds.shape}")
        out = np.zeros((len(feeds), self.agents, self.n_neurons + self.n_inputs), dtype=bool)
        if self.agents < PARALLEL_FROM:
            _run_serial(feeds, self.semantics == "netlogo", out, *self.serial_args)
        else:
            for k in range(len(feeds)):
                out[k] = self.step(feeds[k])
        return out


def _variant(circuit: Circuit, values: dict) -> Circuit:
    """The circuit with one agent's learning values: initial weight first (the w_max check is on it)."""
    if "initial_weight" in values:
        w = values["initial_weight"]
        circuit = dataclasses.replace(
            circuit, synapses=tuple(dataclasses.replace(s, weight=w) if s.plastic else s for s in circuit.synapses)
        )
    fields = {k: v for k, v in values.items() if k in LEARNING_FIELDS}
    return circuit.with_learning_params(**fields) if fields else circuit


def learning_tables(circuit: Circuit, params: dict, agents: int) -> tuple:
    """(stdp [groups, profiles, LO, HI, W(dt)...], group [A], profile [N]): one group per distinct
    row of the learning columns; a profile per (neuron type, learns or not), as the columns set the
    learning neurons only."""
    names = [k for k in params if k in LEARNING_FIELDS or k == "initial_weight"]
    rows = np.column_stack([params[k] for k in names]) if names else np.zeros((agents, 0))
    settings, group = np.unique(rows, axis=0, return_inverse=True)
    learning = {circuit.synapses[k].post for k in circuit.plastic_synapses}
    keys = [(t, n in learning) for n, t in enumerate(circuit.neuron_types)]
    kinds = list(dict.fromkeys(keys))
    profile = np.array([kinds.index(k) for k in keys], dtype=np.int64)
    first = [keys.index(k) for k in kinds]  # a neuron of each profile
    tables = []
    for row in settings:
        types = _variant(circuit, {k: float(v) for k, v in zip(names, row)}).neuron_types
        table, _ = stdp_table(types)
        tables.append(np.column_stack([[types[n].w_min for n in first], [types[n].w_max for n in first], table[first]]))
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
