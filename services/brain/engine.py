"""The spiking-network engine: A agents of one circuit stepped together, one tick per call.

State is a struct of arrays with an agent axis (no per-neuron objects), laid out by build.py;
inside, the agent axis is last so that each phase is one vectorised loop across agents, and the
public views `v`, `w` and `spiked` are [A, ...]. One tick runs five named phases in a fixed order
(docs/tick.md):

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
running its state machine and then at once the pulse queues of its own outgoing synapses. Where
no pulse is due in the tick it is sent, each neuron's turn depends on its own state and on which
senders' turns come before it, so the turns run neuron by neuron across agents (the same updates).

The same circuit, feeds and seeds give the same spikes and weights, bit for bit, whether agents
are stepped alone or together: the only randomness (the netlogo order) is a pure function of
(agent seed, tick). Nothing here knows Zenoh.
"""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads, njit, prange, typeof
from numba.core import types

from services.kernels import compiled
from services.params import PARALLEL_FROM as PARALLEL_FROM
from services.params import agent_columns
from services.snapshots import copy_into

from .build import (
    AT_START,
    BY_RECEIVER,
    COUNT,
    COUNT_FROM_SEND,
    DECAY,
    DELAY,
    DT0_AGAIN,
    FLAGS,
    FLOOR,
    HI,
    HIST_LEN,
    HISTORY,
    INHIBITORY,
    LATENCY,
    LCG_ADD,
    LCG_MUL,
    LEFT,
    LO,
    NEVER,
    PLASTIC,
    POST,
    PRE,
    PULSES,
    REFR_LEFT,
    REFR_PERIOD,
    REFR_V,
    REFRACTORY,
    REOPEN_IN_TURN,
    REST,
    SHUFFLE,
    STDP_OFFSET,
    STREAM,
    SYN_BITS,
    SYN_MASK,
    TABLE,
    THRESHOLD,
    TICK,
    TRAINING,
    agent_seeds,
    build_network,
    check_options,
    initial_weights,
    mix,
    new_state,
)
from .build import DEFAULT_SEMANTICS as DEFAULT_SEMANTICS
from .build import NETLOGO_RULES as NETLOGO_RULES
from .build import ORDERS as ORDERS
from .build import SEMANTICS as SEMANTICS
from .circuit import Circuit
from .netlogo_stream import STREAM_TURNS, ask_draws, next_int, setup_stream

FLOAT64 = np.dtype(np.float64)
# the per-call kernels take any feed of float64 [A, inputs], read only: no per-call check of its layout
FEED_TYPE = types.Array(types.float64, 2, "A", readonly=True)
IDENTITY = np.uint64(0xFEDCBA9876543210)  # the file order of up to 16 neurons, 4 bits each
# the index of a uint64's one set bit: LOWEST_BIT[(bit * DE_BRUIJN) >> 58] (a de Bruijn sequence)
DE_BRUIJN = np.uint64(0x03F79D71B4CB0A89)
LOWEST_BIT = np.zeros(64, np.int64)
LOWEST_BIT[(np.uint64(1) << np.arange(64, dtype=np.uint64)) * DE_BRUIJN >> np.uint64(58)] = np.arange(64)


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
def _feed_and_inputs(lo, hi, t, feed, inpar, syn, n_neurons, counters, ring, spiked, column):
    """Phases 1 (feed) and 2 (inputs), one pass per input neuron (its feed copied first): each
    input neuron is independent."""
    mask = ring.shape[0] - 1
    n_net = syn.shape[0] - feed.shape[1]  # the input neurons' synapses come last, one each
    for i in range(feed.shape[1]):
        node, s = n_neurons + i, n_net + i
        pulses = np.int32(inpar[i, PULSES])
        start = t == 0 and not math.isnan(inpar[i, AT_START])  # the circuit's own feed at tick 0
        slot = (t + syn[s, DELAY]) & mask  # delay 0: delivered in this tick's phase 3
        # One input's feed copied contiguous (`column`, [A]): read across the feed's rows (a stride),
        # the loop below ran as scalar code (LLVM's vector loop assumes a unit stride and checks it):
        # 18.7 against 5.6 ns per agent-tick for the six inputs of the insect circuit.
        for a in range(lo, hi):
            column[a] = inpar[i, AT_START] if start else feed[a, i]
        # Feeds arrive at random, so this loop computes every field and selects (no branches).
        for a in range(lo, hi):
            # 1. feed: an idle input neuron latches x >= 0 (NaN: nothing fed); busy ones ignore it
            x = column[a]
            # The fields are loaded before the selects: a load in a select's arm compiles to a branch.
            left, lat, count = counters[LEFT, node, a], counters[LATENCY, node, a], counters[COUNT, node, a]
            take = (left == 0) & (x >= 0.0) & (x < 1e9)  # NaN and inf fail the tests; & not `and`: no branches
            # floor(x) + 1 (int() is floor() for x >= 0); selected only for x in [0, 1e9), not NaN or inf
            latency = np.int32(x) + np.int32(1)
            lat = latency if take else lat
            count = np.int32(0) if take else count
            left = pulses if take else left
            # 2. inputs: count this tick; a pulse when the count reaches the latency
            count += left > 0
            fired = (left > 0) & (count == lat)
            counters[LATENCY, node, a] = lat
            counters[COUNT, node, a] = np.int32(0) if fired else count
            counters[LEFT, node, a] = left - fired
            spiked[node, a] = fired
            ring[slot, s, a] = fired  # empty: delivered and cleared a ring length ago


@njit(cache=True, inline="always")
def _deliver(lo, hi, t, training, syn, npar, lrn, v, w, counters, last_spike, hist, ring):
    """Phase 3: pulses due now. A REFRACTORY post ignores them (w * r * open is exactly 0 or w),
    but they still count for learning: depression now, and a place in the post's history."""
    slot = t & (ring.shape[0] - 1)
    for s in range(syn.shape[0]):
        post = syn[s, POST]
        if syn[s, FLAGS] & INHIBITORY:
            floor = npar[post, FLOOR]
            for a in range(lo, hi):  # v >= floor always holds, so max() is exact when dv = 0
                dv = w[s, a] * ring[slot, s, a] * (counters[REFR_LEFT, post, a] == 0)
                v[post, a] = max(v[post, a] - dv, floor)
        else:
            for a in range(lo, hi):
                v[post, a] += w[s, a] * ring[slot, s, a] * (counters[REFR_LEFT, post, a] == 0)
        if syn[s, FLAGS] & PLASTIC:
            for a in range(lo, hi):
                if ring[slot, s, a] == 0:
                    continue
                last = last_spike[post, a]
                if training and last != NEVER:  # once per pulse, against the latest post spike
                    _learn(w, s, a, post, t - last, npar, lrn)
                n = counters[HIST_LEN, post, a]
                if n == HISTORY:  # drop the oldest
                    for h in range(HISTORY - 1):
                        hist[a, post, h] = hist[a, post, h + 1]
                    n -= 1
                hist[a, post, n] = (t << SYN_BITS) | s
                counters[HIST_LEN, post, a] = n + 1
        for a in range(lo, hi):
            ring[slot, s, a] = 0


@njit(cache=True, inline="always")
def _fire(lo, hi, t, training, learns, npar, lrn, v, w, counters, last_spike, hist, spiked):
    """Phase 4: refractory clamp, fire at threshold (STDP potentiation), or decay toward rest."""
    for n in range(v.shape[0]):
        threshold, rest, decay = npar[n, THRESHOLD], npar[n, REST], npar[n, DECAY]
        refr_v, period = npar[n, REFR_V], np.int32(npar[n, REFR_PERIOD])
        for a in range(lo, hi):
            refractory = counters[REFR_LEFT, n, a] > 0
            fire = not refractory and v[n, a] >= threshold
            decayed = v[n, a] + (rest - v[n, a]) * decay  # never overshoots rest: decay < 1
            v[n, a] = refr_v if refractory or fire else decayed
            counters[REFR_LEFT, n, a] = period if fire else counters[REFR_LEFT, n, a] - refractory
            last_spike[n, a] = t if fire else last_spike[n, a]
            spiked[n, a] = fire
        for a in range(lo, hi if learns[n] else lo):  # a history only where a plastic synapse comes in
            if spiked[n, a] and counters[HIST_LEN, n, a] > 0:
                if training:  # every remembered arrival is paired with this spike
                    for h in range(counters[HIST_LEN, n, a]):
                        entry = hist[a, n, h]
                        _learn(w, entry & SYN_MASK, a, n, (entry >> SYN_BITS) - t, npar, lrn)
                counters[HIST_LEN, n, a] = 0


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
def _step_range(lo, hi, t, feed, net, st):
    """Tick t for agents lo..hi-1 (unsigned). Arrays have the agent axis last, so each phase is
    a loop across agents; only events (plastic arrivals, spikes of learning neurons) branch."""
    training = st.clock[TRAINING] != 0
    syn, npar, lrn = net.syn, net.npar, (net.stdp, net.group, net.profile)
    v, w, counters, last_spike, hist, ring, spiked = st.v, st.w, st.counters, st.last_spike, st.hist, st.ring, st.spiked
    _feed_and_inputs(lo, hi, t, feed, net.inpar, syn, v.shape[0], counters, ring, spiked, st.feed_column)
    _deliver(lo, hi, t, training, syn, npar, lrn, v, w, counters, last_spike, hist, ring)
    _fire(lo, hi, t, training, net.learns, npar, lrn, v, w, counters, last_spike, hist, spiked)
    _emit(lo, hi, t, syn, feed.shape[1], ring, spiked)


@njit(cache=True)
def _step_serial(feed, net, st):
    _step_range(np.uint64(0), np.uint64(st.v.shape[1]), st.clock[TICK], feed, net, st)
    st.clock[TICK] += 1


@njit(cache=True, parallel=True)
def _step_parallel(feed, net, st, chunks):
    agents = st.v.shape[1]
    for c in prange(chunks):  # one contiguous block of agents per thread
        lo, hi = np.uint64(c * agents // chunks), np.uint64((c + 1) * agents // chunks)
        _step_range(lo, hi, st.clock[TICK], feed, net, st)
    st.clock[TICK] += 1


@njit(cache=True, inline="always")
def order_draw(r, i):
    """One Fisher-Yates step of the netlogo order: the LCG's next state from `r`, and j in 0..i by
    multiply-shift. The device's order (services/gpu_kernels.py compiles this Python); the CPU's
    turns draw the same states by jump-ahead (_netlogo_range), tests/test_gpu.py holds them equal."""
    r = r * LCG_MUL + LCG_ADD
    return r, ((r >> np.uint64(32)) * np.uint64(i + 1)) >> np.uint64(32)


# --- netlogo semantics: the original SpikingLab engine, turn by turn ------------------------------
# Per tick: input neurons (each pulse reaches its target at once), then every neuron in its turn:
# its state machine, then at once the pulse queues of its outgoing synapses. A pulse sent at t on
# a synapse of delay d is counted down from d in the sending tick and delivered at 0, so it
# arrives at t + d - 1 in the sender's turn: before or after the receiver's own turn in that
# tick, depending on the order (effective delay d - 1 or d).


@njit(cache=True, inline="always")
def _netlogo_by_receiver(lo, hi, t, net, st):
    """The netlogo turns of tick t for agents lo..hi-1, neuron by neuron across agents rather than
    agent by agent in turn order: the same updates in the same order, for a network where no pulse
    reaches its post in the tick it is sent (BY_RECEIVER). Then a turn changes only its own neuron,
    the weights onto it and pulses due in later ticks; a pulse due now is delivered in its sender's
    turn and changes only its post and its own weight. So each neuron's tick is its own: the
    arrivals whose senders come before it in the order (in the order of the senders' turns), its
    state machine, then the rest. The order is the draws' permutation (row 1 of draws_flat).

    As _netlogo_range, one function with no calls in its loops: the plastic arrival shared with
    it as an inline helper took both kernels to half their speed (A = 1,000, `bench engine --orders`
    in turns: 13.1-13.4 M against 27.0-28.6 M by receiver, 10.3-11.9 against 15.3-17.0 M one by one)."""
    syn, npar, stdp, group, profile = net.syn, net.npar, net.stdp, net.group, net.profile
    out_start, out_syn, in_start, in_syn, rules = net.out_start, net.out_syn, net.in_start, net.in_syn, net.rules
    training = st.clock[TRAINING] != 0
    hist, ring = st.hist, st.ring
    n_neurons, agents = st.v.shape[0], np.uint64(st.v.shape[1])
    v1, w1, spiked1, last1 = st.v_flat, st.w_flat, st.spiked_flat, st.last_spike_flat
    refr1, left1, hlen1, ring1 = st.refractory_flat, st.refr_left_flat, st.hist_len_flat, st.ring_flat
    draws, places, arrived, agent_list = st.draws_flat, st.places, st.arrived_flat, st.agent_list
    mask = ring.shape[0] - 1
    ring_now = np.uint64(t & mask) * np.uint64(ring.shape[1]) * agents
    width = stdp.shape[2] - TABLE
    send = np.int64(1) if rules & COUNT_FROM_SEND else np.int64(0)
    reopen = (rules & REOPEN_IN_TURN) != 0
    for a in range(lo, hi):  # each neuron's place in the order, 4 bits each: the order's inverse
        places[a] = np.uint64(0) if rules & SHUFFLE else IDENTITY
    for k in range(n_neurons if rules & SHUFFLE else 0):
        for a in range(lo, hi):
            n = (draws[agents + a] >> np.uint64(4 * k)) & np.uint64(15)
            places[a] |= np.uint64(k) << (n * np.uint64(4))
    arrivals = np.empty(max(1, in_syn.shape[0]), np.uint64)  # one agent's arrivals at one neuron, by turn
    for p in range(n_neurons):
        row, at, first, last_in = np.uint64(p) * agents, np.uint64(4 * p), in_start[p], in_start[p + 1]
        rest, threshold, decay, refr_v = npar[p, REST], npar[p, THRESHOLD], npar[p, DECAY], npar[p, REFR_V]
        period, floor, offset = np.int32(npar[p, REFR_PERIOD]), npar[p, FLOOR], np.int64(npar[p, STDP_OFFSET])
        prof = profile[p]
        for a in range(lo, hi):  # its pulses due now, one bit per incoming synapse: row 0 before its turn, 1 after
            arrived[a], arrived[agents + a] = 0, 0
        for i in range(first, last_in):
            s, bit = in_syn[i], np.uint64(1) << np.uint64(i - first)
            due_at, pre_at = ring_now + s * agents, np.uint64(4 * syn[s, PRE])
            for a in range(lo, hi):
                early = (places[a] >> pre_at) & np.uint64(15) < (places[a] >> at) & np.uint64(15)
                due = ring1[due_at + a] != 0
                ring1[due_at + a] = 0
                arrived[a] |= bit if due & early else np.uint64(0)
                arrived[agents + a] |= np.uint64(0) if early else (bit if due else np.uint64(0))
        for stage in range(2):  # 0: arrivals from the turns before this neuron's; 1: its turn, then the rest
            if stage == 1:
                # The state machine as the turns run it, by selects: one vector loop across agents.
                for a in range(lo, hi):
                    pa = row + a
                    refractory = refr1[pa] != 0
                    vn = v1[pa]
                    fire = (not refractory) & (vn != rest) & (vn >= threshold)
                    left = left1[pa] - refractory
                    left1[pa] = period if fire else left
                    refr1[pa] = np.int32(1) if fire else np.int32(refractory & ((left > 0) | (not reopen)))
                    decayed = vn + (rest - vn) * decay
                    v1[pa] = refr_v if refractory else (vn if fire | (vn == rest) else decayed)
                    last1[pa] = t if fire else last1[pa]
                    spiked1[pa] = fire
                for a in range(lo, hi if net.learns[p] else lo):  # a spike: potentiation over the history
                    pa = row + a
                    if not spiked1[pa]:
                        continue
                    g = group[a]
                    lo_w, hi_w = stdp[g, prof, LO], stdp[g, prof, HI]
                    for h in range(hlen1[pa]):
                        entry = hist[a, p, h]
                        s, dt = entry & SYN_MASK, (entry >> SYN_BITS) - t
                        if 0 <= dt + offset < width:
                            sa = s * agents + a
                            w1[sa] = min(max(w1[sa] + stdp[g, prof, TABLE + dt + offset], lo_w), hi_w)
                    hlen1[pa] = 0
                for q in range(out_start[p], out_start[p + 1]):  # pulses out, due in a later tick
                    s = out_syn[q]
                    slot = np.uint64((t + syn[s, DELAY] - send) & mask)
                    base = (slot * np.uint64(ring.shape[1]) + s) * agents
                    for a in range(lo, hi):
                        ring1[base + a] = spiked1[row + a]
            due_row, listed = np.uint64(stage) * agents, lo
            if last_in - first == 1 and not (training and syn[in_syn[first], FLAGS] & PLASTIC):
                s = in_syn[first]  # one synapse in, nothing to learn: a vector loop of selects
                inhibitory = (syn[s, FLAGS] & INHIBITORY) != 0
                for a in range(lo, hi):
                    pa, sa = row + a, s * agents + a
                    vp, ws = v1[pa], w1[sa]
                    changed = max(vp - ws, floor) if inhibitory else vp + ws
                    v1[pa] = changed if (arrived[due_row + a] != 0) & (refr1[pa] == 0) else vp
                continue
            for a in range(lo, hi if last_in > first else lo):  # the agents with arrivals, listed without a branch
                agent_list[listed] = a
                listed += np.uint64(arrived[due_row + a] != 0)
            for k in range(lo, listed):
                a = agent_list[k]
                pa, due = row + a, arrived[due_row + a]
                m = 0  # the arrivals of this stage, by their senders' turns (stable: file order within one)
                while due:
                    low = due & (~due + np.uint64(1))
                    due ^= low
                    s = in_syn[first + LOWEST_BIT[(low * DE_BRUIJN) >> np.uint64(58)]]
                    key = (places[a] >> np.uint64(4 * syn[s, PRE])) & np.uint64(15)
                    j = m
                    while j > 0 and (places[a] >> np.uint64(4 * syn[arrivals[j - 1], PRE])) & np.uint64(15) > key:
                        arrivals[j] = arrivals[j - 1]
                        j -= 1
                    arrivals[j] = s
                    m += 1
                for i in range(m):
                    # NetLogo receive-pulse, as in _netlogo_range's turns
                    s = arrivals[i]
                    sa = s * agents + a
                    vp, ws = v1[pa], w1[sa]
                    changed = max(vp - ws, floor) if syn[s, FLAGS] & INHIBITORY else vp + ws
                    v1[pa] = changed if refr1[pa] == 0 else vp
                    if not (training & ((syn[s, FLAGS] & PLASTIC) != 0)):
                        continue
                    n_hist = hlen1[pa]
                    if n_hist > HISTORY:
                        for h in range(n_hist - 1):
                            hist[a, p, h] = hist[a, p, h + 1]
                        n_hist -= 1
                    hist[a, p, n_hist] = (t << SYN_BITS) | s
                    hlen1[pa] = n_hist + 1
                    g, last = group[a], last1[pa]
                    lo_w, hi_w = stdp[g, prof, LO], stdp[g, prof, HI]
                    if rules & DT0_AGAIN:
                        for h in range(n_hist + 1):
                            entry = hist[a, p, h]
                            if (entry >> SYN_BITS) != last:
                                break
                            ea = (entry & SYN_MASK) * agents + a
                            if 0 <= offset < width:
                                w1[ea] = min(max(w1[ea] + stdp[g, prof, TABLE + offset], lo_w), hi_w)
                        depress = t > last
                    else:
                        depress = True
                    dt = t - last
                    if depress and 0 <= dt + offset < width:
                        w1[sa] = min(max(w1[sa] + stdp[g, prof, TABLE + dt + offset], lo_w), hi_w)


@njit(cache=True, inline="always")
def _netlogo_range(lo, hi, t, feed, net, st):
    """NetLogo tick t for agents lo..hi-1: what precedes the turns (the feed, input pulses, the end
    of refractory periods, which neurons have pulses due, the random order's draws and, up to 16
    neurons, its swaps) as vector loops across agents, then each agent's turns in sequence (or,
    where the network allows, neuron by neuron across agents: _netlogo_by_receiver).

    Of a neuron's whole history only two kinds of entry change w when a plastic pulse arrives:
    every remembered arrival came at or after the post's last spike (the history is cleared when
    it fires) and each was depressed once, at its own arrival. So those at dt = 0 (arrived in the
    spike's tick, after it: they potentiate again at every arrival, NetLogo's dt = 0 quirk), which
    are a prefix, and the new arrival itself (depressed once if dt > 0). Running just those, in
    history order, gives the same weights as NetLogo's full pass.

    One function with no calls in its loops: numba counts references to each array handed to a
    helper, inlined or not, and in the turns those atomic counts cost more than the turns (a third
    of the one-thread tick at A = 1,000)."""
    syn, npar, inpar, stdp, group, profile = net.syn, net.npar, net.inpar, net.stdp, net.group, net.profile
    out_start, out_syn, order_key, jump, rules = net.out_start, net.out_syn, net.order_key, net.order_jump, net.rules
    clock, v, w, counters, hist, ring = st.clock, st.v, st.w, st.counters, st.hist, st.ring
    stream, stream_order = st.stream, net.stream_order
    training = clock[TRAINING] != 0
    n_neurons = v.shape[0]
    _feed_and_inputs(lo, hi, t, feed, inpar, syn, n_neurons, counters, ring, st.spiked, st.feed_column)  # input pulses
    mask = ring.shape[0] - 1
    now = np.uint64(t & mask)
    n_net = syn.shape[0] - feed.shape[1]
    width = stdp.shape[2] - TABLE  # W(dt) is stdp[g, p, TABLE + dt + offset] for 0 <= dt + offset < width
    send = np.int64(1) if rules & COUNT_FROM_SEND else np.int64(0)  # count-down ticks used in the sending tick
    reopen = (rules & REOPEN_IN_TURN) != 0
    agents = np.uint64(v.shape[1])  # the turns read flat views (build.FLAT_VIEWS): index n * agents + a
    v1, w1, spiked1, last1 = st.v_flat, st.w_flat, st.spiked_flat, st.last_spike_flat
    refr1, left1, hlen1, ring1 = st.refractory_flat, st.refr_left_flat, st.hist_len_flat, st.ring_flat
    due1 = st.due_flat
    ring_now = now * np.uint64(ring.shape[1]) * agents  # slot now's first synapse in ring1
    # What comes before the turns depends on each agent's state alone: one vector loop across agents each.
    if not reopen:  # refractory periods that ended in the last tick end now
        for n in range(n_neurons):
            for a in range(lo, hi):
                closed, left = counters[REFRACTORY, n, a], counters[REFR_LEFT, n, a]
                counters[REFRACTORY, n, a] = closed if left > 0 else np.int32(0)
    for s in range(n_net, syn.shape[0]):  # input neurons: straight to their target, not plastic
        post = syn[s, POST]
        for a in range(lo, hi):
            arrived, vp, ws, closed = ring[now, s, a] != 0, v[post, a], w[s, a], counters[REFRACTORY, post, a]
            ring[now, s, a] = 0
            v[post, a] = vp + ws if arrived & (closed == 0) else vp
    # The random order: each agent's Fisher-Yates draws across agents (vector loops), then the
    # swaps. Row 0 of `draws`: the LCG's start, a hash of (seed, tick); step i's r by jump-ahead,
    # j in 0..i by multiply-shift. Up to 16 neurons, the swaps too, on a permutation packed in
    # row 1 (4 bits a neuron); else row i + 1 keeps step i's j for the agent's own swaps.
    draws, packed = st.draws_flat, n_neurons <= 16
    if rules & SHUFFLE:
        for a in range(lo, hi):
            draws[a] = mix(order_key[a] + np.uint64(t))
            if packed:
                draws[agents + a] = IDENTITY
        for i in range(n_neurons - 1, 0, -1):
            m0, m1 = jump[0, n_neurons - i], jump[1, n_neurons - i]
            row, si = np.uint64(i + 1) * agents, np.uint64(4 * i)
            for a in range(lo, hi):
                r = draws[a] * m0 + m1  # order_draw's r
                j = ((r >> np.uint64(32)) * np.uint64(i + 1)) >> np.uint64(32)
                if packed:  # swap the 4 bits of i and j
                    perm, sj = draws[agents + a], j * np.uint64(4)
                    x = ((perm >> si) ^ (perm >> sj)) & np.uint64(15)
                    draws[agents + a] = perm ^ ((x << si) | (x << sj))
                else:
                    draws[row + a] = j
    if rules & BY_RECEIVER:
        _netlogo_by_receiver(lo, hi, t, net, st)
        return
    for n in range(n_neurons):  # which neurons have pulses due now: most turns deliver none
        row = np.uint64(n) * agents
        for a in range(lo, hi):
            due1[row + a] = 0
    for s in range(n_net):
        pre = np.uint64(syn[s, PRE])
        for a in range(lo, hi):
            due1[pre * agents + a] |= ring[now, s, a]
    order = np.empty(n_neurons, np.uint64)  # the k-th neuron to take its turn; unsigned: no negative-index checks
    for a in range(lo, hi):
        g = group[a]
        perm = draws[agents + a] if rules & SHUFFLE and packed else IDENTITY
        for n in range(n_neurons):
            order[n] = (perm >> np.uint64(4 * n)) & np.uint64(15) if packed else np.uint64(n)
        if rules & SHUFFLE and not packed:
            for i in range(n_neurons - 1, 0, -1):
                j = draws[np.uint64(i + 1) * agents + a]
                order[i], order[j] = order[j], order[i]
        if rules & STREAM:  # NetLogo's draws before the turns (netlogo_stream.py): the world's asks,
            ask_draws(stream, a, 3)  # ask visualsensors, twice
            ask_draws(stream, a, 3)
            ask_draws(stream, a, feed.shape[1])  # ask inputneurons
            for k in range(n_neurons):  # ask normalneurons, whose shufflerator draws its first now
                order[k] = stream_order[k]
            j = next_int(stream, a, n_neurons)
            order[0], order[j] = order[j], order[0]
        for k in range(n_neurons):
            if rules & STREAM and k + 2 < n_neurons:  # each turn but the last two draws the next one first
                j = k + 1 + next_int(stream, a, n_neurons - k - 1)
                order[k + 1], order[j] = order[j], order[k + 1]
            n = order[k]
            na = n * agents + a
            spiked1[na] = 0
            # The state machine computes every field and selects, but for firing: the random order
            # makes its branches unpredictable. Refractory: one tick of the period, held at the
            # refractory potential (with REOPEN_IN_TURN open again at its end, so that later
            # arrivals in this tick count); else decay toward rest, or fire at threshold.
            refractory = refr1[na] != 0
            vn, rest = v1[na], npar[n, REST]
            fire = (not refractory) & (vn != rest) & (vn >= npar[n, THRESHOLD])
            left = left1[na] - refractory
            left1[na] = left
            refr1[na] = refractory & ((left > 0) | (not reopen))
            refr_v, decayed = npar[n, REFR_V], vn + (rest - vn) * npar[n, DECAY]  # both first: selects, not branches
            v1[na] = refr_v if refractory else (vn if fire | (vn == rest) else decayed)
            if fire:  # potentiation over the history, pulses out
                last1[na] = t
                p, offset = profile[n], np.int64(npar[n, STDP_OFFSET])
                for h in range(hlen1[na]):
                    entry = hist[a, n, h]
                    s, dt = entry & SYN_MASK, (entry >> SYN_BITS) - t
                    if 0 <= dt + offset < width:  # STDP: w += W(dt), clipped to [w_min, w_max]
                        dw = stdp[g, p, TABLE + dt + offset]
                        sa = s * agents + a
                        w1[sa] = min(max(w1[sa] + dw, stdp[g, p, LO]), stdp[g, p, HI])
                hlen1[na] = 0
                for q in range(out_start[n], out_start[n + 1]):
                    s = out_syn[q]
                    slot = np.uint64((t + syn[s, DELAY] - send) & mask)
                    ring[slot, s, a] = 1
                    due1[na] |= slot == now  # delay 1 counted from the sending tick: due in this turn
                if rules & STREAM:  # propagate-pulses: an ask over the outgoing synapses
                    ask_draws(stream, a, out_start[n + 1] - out_start[n])
                refr1[na] = 1
                left1[na] = np.int32(npar[n, REFR_PERIOD])
                spiked1[na] = 1
            if rules & STREAM:  # do-synaptic-dynamics: an ask over the outgoing synapses with pulses in flight
                busy = 0
                for q in range(out_start[n], out_start[n + 1]):
                    for slot in range(ring.shape[0]):
                        if ring[slot, out_syn[q], a]:
                            busy += 1
                            break
                ask_draws(stream, a, busy)
                stream[a, STREAM_TURNS + k] = n
            if not due1[na]:
                continue
            for q in range(out_start[n], out_start[n + 1]):  # its synapses' pulses due now
                # NetLogo receive-pulse: potential change unless REFRACTORY (computed and selected,
                # as in the state machine); a plastic arrival in training is remembered, and STDP
                # runs over the post's history (see above)
                s = out_syn[q]
                flags, post = syn[s, FLAGS], syn[s, POST]
                sa, pa = s * agents + a, np.uint64(post) * agents + a
                arrived = ring1[ring_now + sa] != 0
                ring1[ring_now + sa] = 0
                vp, ws = v1[pa], w1[sa]
                inhibited, excited = max(vp - ws, npar[post, FLOOR]), vp + ws
                changed = inhibited if flags & INHIBITORY else excited
                v1[pa] = changed if arrived & (refr1[pa] == 0) else vp
                if not (arrived & training & ((flags & PLASTIC) != 0)):
                    continue
                m = hlen1[pa]
                if m > HISTORY:  # NetLogo drops the oldest when it holds more than 30, then appends: up to 31
                    for h in range(m - 1):
                        hist[a, post, h] = hist[a, post, h + 1]
                    m -= 1
                hist[a, post, m] = (t << SYN_BITS) | s
                hlen1[pa] = m + 1
                last = last1[pa]
                p, offset = profile[post], np.int64(npar[post, STDP_OFFSET])
                lo_w, hi_w = stdp[g, p, LO], stdp[g, p, HI]
                if rules & DT0_AGAIN:
                    for h in range(m + 1):  # the dt = 0 prefix (the new arrival too, when it is at dt = 0)
                        entry = hist[a, post, h]
                        if (entry >> SYN_BITS) != last:
                            break
                        ea = (entry & SYN_MASK) * agents + a
                        if 0 <= offset < width:
                            w1[ea] = min(max(w1[ea] + stdp[g, p, TABLE + offset], lo_w), hi_w)
                    depress = t > last  # the new arrival's one depression
                else:  # the new arrival alone: potentiation at dt = 0, else its one depression
                    depress = True
                dt = t - last
                if depress and 0 <= dt + offset < width:
                    w1[sa] = min(max(w1[sa] + stdp[g, p, TABLE + dt + offset], lo_w), hi_w)


@njit(cache=True)
def _netlogo_serial(feed, net, st):
    _netlogo_range(np.uint64(0), np.uint64(st.v.shape[1]), st.clock[TICK], feed, net, st)
    st.clock[TICK] += 1


@njit(cache=True)
def _netlogo_block(lo, hi, t, feed, net, st):
    """One thread's block of agents: a function of its own, compiled as the one-thread tick is
    (inlined into the parallel loop's body, the turns compiled to slower code)."""
    _netlogo_range(lo, hi, t, feed, net, st)


@njit(cache=True, parallel=True)
def _netlogo_parallel(feed, net, st, chunks):
    agents = st.v.shape[1]
    for c in prange(chunks):
        lo, hi = np.uint64(c * agents // chunks), np.uint64((c + 1) * agents // chunks)
        _netlogo_block(lo, hi, st.clock[TICK], feed, net, st)
    st.clock[TICK] += 1


@njit(cache=True, inline="always")
def serial_tick(netlogo, feed, net, st):
    """One tick of either semantics on one thread, for Engine.run's compiled loop of many ticks;
    `net` and `st` are Engine.structs."""
    if netlogo:
        _netlogo_serial(feed, net, st)
    else:
        _step_serial(feed, net, st)


@njit(cache=True, inline="always")
def range_tick(netlogo, lo, hi, t, feed, net, st):
    """Tick t of either semantics for agents lo..hi-1 only, the clock left alone: for compiled
    loops that step blocks of agents on several threads, each block many ticks on (agents are
    independent), and move the clock on once after (services.loop's parallel fused loop)."""
    lo, hi = np.uint64(lo), np.uint64(hi)
    if netlogo:
        _netlogo_range(lo, hi, t, feed, net, st)
    else:
        _step_range(lo, hi, t, feed, net, st)


@njit(cache=True)
def _run_serial(feeds, netlogo, out, net, st):
    """Engine.run's ticks in one call: feeds [T, A, inputs] -> out [T, A, nodes]."""
    spiked = st.spiked
    for k in range(feeds.shape[0]):
        serial_tick(netlogo, feeds[k], net, st)
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
    is drawn from seed + a and t), "file" (circuit file order every tick) or "netlogo-stream"
    (NetLogo's own stream as the SpikingLab source's setup leaves it after `random-seed
    netlogo_seed`, the same for every agent, drawn from as the source does: docs/netlogo-random.md;
    `turns` is then each agent's order of the last tick), and `without` names
    NetLogo rules to switch off one at a time (NETLOGO_RULES; for ablations, not for use). `seed`
    may also be one seed per agent (an array [A]; agents taken from a larger population).

    `params`: per-agent parameters (services.params, the brain's columns: A+, A-, tau+/-, w_max,
    initial weight, input gain), each a number or one value per agent; agents with the same
    values share one STDP table.

    The netlogo turns run neuron by neuron across agents (_netlogo_by_receiver) where the network
    allows it and there are at least BY_RECEIVER_FROM agents, else agent by agent in turn order:
    the same results. `by_receiver=False` keeps them agent by agent (for tests and benchmarks).
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
        netlogo_seed: int | None = None,
        by_receiver: bool = True,
    ):
        check_options(agents, semantics, order, without, netlogo_seed)
        self.circuit, self.agents = circuit, agents
        self.semantics, self.order, self.without = semantics, order, tuple(without)
        self.seeds = agent_seeds(seed, agents)
        self.params = agent_columns(agents, params, "brain")
        self.network = build_network(circuit, self.params, self.seeds, semantics, order, without, by_receiver)
        self.initial_weights = initial_weights(circuit, self.params, agents)
        self.state = new_state(circuit, agents, stream=order == "netlogo-stream")
        self.stream_start = None  # the stream's row as setup leaves it (order netlogo-stream)
        if order == "netlogo-stream" and netlogo_seed is not None:  # check_options: it is not None
            self.stream_start = setup_stream(netlogo_seed, len(circuit.neuron_names))
        self.n_neurons, self.n_inputs, self.n_synapses = (
            len(circuit.neuron_names),
            len(circuit.inputs),
            len(circuit.synapses),
        )
        self.no_feed = np.full((agents, self.n_inputs), np.nan)
        self.no_feed.flags.writeable = False  # the kernels never write a feed
        self.v = self.state.v.T  # [A, neurons] membrane potentials
        self.w = self.state.w.T  # [A, synapses] weights
        self.spiked = self.state.spiked.view(np.bool_).T  # [A, nodes] who spiked in the last tick
        self.structs = (self.network.struct(), self.state.struct())  # the kernels' arguments after the feed
        self._tick, self._args = self._kernel()
        self.training = training
        self.reset()

    def _kernel(self):
        """The compiled per-call tick for this engine's semantics and size, and its arguments after the feed."""
        netlogo = self.semantics == "netlogo"
        signature = (FEED_TYPE, *(typeof(s) for s in self.structs))
        if self.agents >= PARALLEL_FROM:
            kernel = _netlogo_parallel if netlogo else _step_parallel
            return compiled(kernel, (*signature, types.int64)), (*self.structs, get_num_threads())
        return compiled(_netlogo_serial if netlogo else _step_serial, signature), self.structs

    def reset(self) -> None:
        """Back to tick 0: potentials at rest, initial weights, nothing in flight."""
        st = self.state
        st.clock[TICK] = 0
        self.v[:] = self.network.npar[: self.n_neurons, REST]
        self.w[:] = self.initial_weights
        st.counters[:] = 0
        st.last_spike[:] = 0 if self.semantics == "netlogo" else NEVER  # NetLogo's variables start at 0
        st.hist[:] = 0
        st.ring[:] = 0
        st.spiked[:] = 0
        if self.stream_start is not None:
            st.stream[:] = self.stream_start

    @property
    def tick(self) -> int:
        """The tick the next step() will run."""
        return int(self.state.clock[TICK])

    @property
    def turns(self) -> np.ndarray:
        """[A, neurons]: each agent's neurons in the order of their turns in the last tick (order
        netlogo-stream only; a view the next step overwrites)."""
        if self.stream_start is None:
            raise ValueError(f"turns are kept for order netlogo-stream only, this engine's is {self.order}")
        return self.state.stream[:, STREAM_TURNS:]

    @property
    def training(self) -> bool:
        return bool(self.state.clock[TRAINING])

    @training.setter
    def training(self, on: bool) -> None:
        self.state.clock[TRAINING] = 1 if on else 0

    def step(self, feed: np.ndarray | None = None) -> np.ndarray:
        """Run one tick with `feed` ([A, inputs] values, NaN = nothing fed; None: nothing at all).

        Returns `spiked`, a bool view [A, nodes] that the next step overwrites.
        """
        if feed is None:
            feed = self.no_feed
        elif feed.__class__ is not np.ndarray or feed.dtype is not FLOAT64 or feed.shape != self.no_feed.shape:
            feed = self._checked_feed(feed)
        self._tick(feed, *self._args)
        return self.spiked

    def _checked_feed(self, feed) -> np.ndarray:
        feed = np.array(feed, dtype=np.float64)  # a copy: a plain ndarray in the machine's byte order
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
        st = self.state
        arrays = {"clock": st.clock, "v": st.v, "w": st.w, "state": st.counters, "last_spike": st.last_spike}
        stream = {"stream": st.stream} if self.stream_start is not None else {}
        return arrays | {"hist": st.hist, "ring": st.ring, "spiked": st.spiked} | stream

    def get_weights(self) -> np.ndarray:
        """A copy of all synapse weights, [A, synapses] (checkpoints)."""
        return self.w.copy()

    def set_weights(self, weights) -> None:
        """Replace all weights ([synapses] for every agent, or [A, synapses]); plastic ones must be in range."""
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape == (self.n_synapses,):
            weights = np.broadcast_to(weights, self.w.shape)
        if weights.shape != self.w.shape:
            raise ValueError(f"weights must have shape {self.w.shape} or ({self.n_synapses},), got {weights.shape}")
        if not np.all(np.isfinite(weights)) or np.any(weights <= 0):
            raise ValueError("weights must be finite and > 0")
        net = self.network
        post = net.syn[:, POST]
        plastic = (net.syn[:, FLAGS] & PLASTIC) != 0
        limits = net.stdp[net.group[:, None], net.profile[post][None, :]]  # [A, S, LO..HI]
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
        between ticks)."""
        feeds = np.ascontiguousarray(feeds, dtype=np.float64)  # only read by the kernels
        if feeds.ndim != 3 or feeds.shape[1:] != self.no_feed.shape:
            raise ValueError(f"feeds must have shape (ticks, {self.agents}, {self.n_inputs}), got {feeds.shape}")
        out = np.zeros((len(feeds), self.agents, self.n_neurons + self.n_inputs), dtype=bool)
        if self.agents < PARALLEL_FROM:
            _run_serial(feeds, self.semantics == "netlogo", out, *self.structs)
        else:
            for k in range(len(feeds)):
                out[k] = self.step(feeds[k])
        return out
