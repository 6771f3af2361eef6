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

There is no randomness inside the engine: the same circuit and feeds give the same spikes and
weights, bit for bit, whether agents are stepped alone or together. Nothing here knows Zenoh.
"""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads, njit, prange

from .circuit import Circuit
from .stdp import stdp_table

HISTORY = 30  # arrivals a neuron remembers since its last spike (oldest dropped)
NEVER = -(2**62)  # last-spike tick of a neuron that has not fired yet
SYN_BITS = 16  # a history entry packs (arrival tick << SYN_BITS) | synapse index
SYN_MASK = (1 << SYN_BITS) - 1

# npar columns: per-neuron parameters (from its type), then W(dt) for dt = -STDP_OFFSET.. (stdp.py)
REST, THRESHOLD, DECAY, REFR_V, REFR_PERIOD, FLOOR, W_MIN, W_MAX, STDP_OFFSET, STDP = range(10)
# syn columns; flags bits
PRE, POST, DELAY, FLAGS = 0, 1, 2, 3
INHIBITORY, PLASTIC = 1, 2
# node state planes [3, nodes, A] (int32): for neurons ...
REFR_LEFT, HIST_LEN = 0, 1
# ... and for input neurons (the nodes after the neurons): ticks counted, pulses left, latency
COUNT, LEFT, LATENCY = 0, 1, 2
# inpar columns: per input neuron
PULSES, AT_START = 0, 1
# clock: [tick, training]
TICK, TRAINING = 0, 1


@njit(cache=True, inline="always")
def _learn(w, s, a, post, dt, npar):
    """STDP: w[s, a] += W(dt) from the post neuron's table, clipped to [w_min, w_max]."""
    k = dt + int(npar[post, STDP_OFFSET])
    if 0 <= k < npar.shape[1] - STDP:
        w[s, a] = min(max(w[s, a] + npar[post, STDP + k], npar[post, W_MIN]), npar[post, W_MAX])


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
def _deliver(lo, hi, t, training, syn, npar, v, w, state, last_spike, hist, ring):
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
                    _learn(w, s, a, post, t - last, npar)
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
def _fire(lo, hi, t, training, npar, v, w, state, last_spike, hist, spiked):
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
                        _learn(w, entry & SYN_MASK, a, n, (entry >> SYN_BITS) - t, npar)
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
def _step_range(lo, hi, feed, clock, syn, npar, inpar, v, w, state, last_spike, hist, ring, spiked):
    """One tick for agents lo..hi-1 (unsigned). Arrays have the agent axis last, so each phase is
    a loop across agents; only events (plastic arrivals, spikes of learning neurons) branch."""
    t = clock[TICK]
    training = clock[TRAINING] != 0
    _feed_and_inputs(lo, hi, t, feed, inpar, syn, v.shape[0], state, ring, spiked)
    _deliver(lo, hi, t, training, syn, npar, v, w, state, last_spike, hist, ring)
    _fire(lo, hi, t, training, npar, v, w, state, last_spike, hist, spiked)
    _emit(lo, hi, t, syn, feed.shape[1], ring, spiked)


@njit(cache=True)
def _step_serial(feed, clock, syn, npar, inpar, v, w, state, last_spike, hist, ring, spiked):
    _step_range(np.uint64(0), np.uint64(v.shape[1]), feed, clock, syn, npar, inpar, v, w, state,
                last_spike, hist, ring, spiked)
    clock[TICK] += 1


@njit(cache=True, parallel=True)
def _step_parallel(feed, clock, syn, npar, inpar, v, w, state, last_spike, hist, ring, spiked, chunks):
    agents = v.shape[1]
    for c in prange(chunks):  # one contiguous block of agents per thread
        lo, hi = np.uint64(c * agents // chunks), np.uint64((c + 1) * agents // chunks)
        _step_range(lo, hi, feed, clock, syn, npar, inpar, v, w, state, last_spike, hist, ring, spiked)
    clock[TICK] += 1


PARALLEL_FROM = 256  # agents; below this, thread start-up costs more than it saves


class Engine:
    """A agents of one circuit (same synapses, independent potentials, pulses and weights).

    Per tick: call `step(feed)` with the sensor values (shape [A, inputs], NaN = nothing fed; or
    no argument when nothing is fed), then read `spiked` ([A, nodes]: neurons then input
    neurons), `v` and `w`.
    """

    def __init__(self, circuit: Circuit, agents: int = 1, training: bool = True):
        if agents < 1:
            raise ValueError(f"agents must be >= 1, got {agents}")
        self.circuit = circuit
        self.agents = agents
        c = circuit
        self.n_neurons, self.n_inputs, self.n_synapses = len(c.neuron_names), len(c.inputs), len(c.synapses)
        self.syn = np.array(
            [[s.pre, s.post, s.delay, INHIBITORY * s.inhibitory | PLASTIC * s.plastic] for s in c.synapses],
            dtype=np.int64,
        ).reshape(self.n_synapses, 4)
        table, offset = stdp_table(c.neuron_types)
        self.npar = np.hstack([
            np.array([[t.rest, t.threshold, t.decay, t.refractory_potential, t.refractory_period, t.floor,
                       t.w_min, t.w_max, offset] for t in c.neuron_types], dtype=np.float64),
            table,
        ])
        self.inpar = np.array(
            [[i.pulses, np.nan if i.at_start is None else i.at_start] for i in c.inputs], dtype=np.float64
        ).reshape(self.n_inputs, 2)
        self.initial_weights = np.array([s.weight for s in c.synapses], dtype=np.float64)
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
        self.hist = np.zeros((A, N, HISTORY), dtype=np.int64)  # used per event: agent-major
        self.ring = np.empty((ring_len, S, A), dtype=np.uint8)
        self._spiked = np.zeros((N + I, A), dtype=np.uint8)
        self.v = self._v.T  # [A, neurons] membrane potentials
        self.w = self._w.T  # [A, synapses] weights
        self.spiked = self._spiked.view(np.bool_).T  # [A, nodes] who spiked in the last tick
        self._args = (self.clock, self.syn, self.npar, self.inpar, self._v, self._w,
                      self.state, self.last_spike, self.hist, self.ring, self._spiked)
        if agents >= PARALLEL_FROM:
            self._call, self._args = _step_parallel, self._args + (get_num_threads(),)
        else:
            self._call = _step_serial
        self.training = training
        self.reset()

    def reset(self) -> None:
        """Back to tick 0: potentials at rest, initial weights, nothing in flight."""
        self.clock[TICK] = 0
        N = self.n_neurons
        self.v[:] = self.npar[:N, REST]
        self.w[:] = self.initial_weights
        self.state[:] = 0
        self.last_spike[:] = NEVER
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
        elif (type(feed) is not np.ndarray or feed.dtype != np.float64 or feed.shape != self.no_feed.shape
              or not feed.flags.c_contiguous):
            feed = self._checked_feed(feed)
        self._call(feed, *self._args)
        return self.spiked

    def _checked_feed(self, feed) -> np.ndarray:
        feed = np.ascontiguousarray(feed, dtype=np.float64)
        if feed.shape != self.no_feed.shape:
            raise ValueError(f"feed must have shape {self.no_feed.shape} (agents, inputs), got {feed.shape}")
        return feed

    def get_weights(self) -> np.ndarray:
        """A copy of all synapse weights, [A, synapses] (checkpoints)."""
        return self.w.copy()

    def set_weights(self, weights) -> None:
        """Replace all weights ([synapses] for every agent, or [A, synapses]); plastic ones must be in range."""
        weights = np.broadcast_to(np.asarray(weights, dtype=np.float64), self.w.shape) if np.ndim(weights) == 1 \
            else np.asarray(weights, dtype=np.float64)
        if weights.shape != self.w.shape:
            raise ValueError(f"weights must have shape {self.w.shape} or ({self.n_synapses},), got {weights.shape}")
        if not np.all(np.isfinite(weights)) or np.any(weights <= 0):
            raise ValueError("weights must be finite and > 0")
        post = self.syn[:, POST]
        plastic = (self.syn[:, FLAGS] & PLASTIC) != 0
        lo, hi = self.npar[post, W_MIN], self.npar[post, W_MAX]
        bad = plastic & ((weights < lo) | (weights > hi)).any(axis=0)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(f"weight of plastic synapse {self.circuit.synapse_label(k)} outside [{lo[k]}, {hi[k]}]")
        self.w[:] = weights

    def run(self, feeds: np.ndarray) -> np.ndarray:
        """Step len(feeds) ticks with feeds [T, A, inputs]; returns the spikes [T, A, nodes]."""
        out = np.zeros((len(feeds), self.agents, self.n_neurons + self.n_inputs), dtype=bool)
        for k in range(len(feeds)):
            out[k] = self.step(feeds[k])
        return out
