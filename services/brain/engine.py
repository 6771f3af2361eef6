"""The spiking-network engine: A agents of one circuit stepped together, one tick per call.

State is a struct of arrays with the agent axis first (no per-neuron objects). One tick runs five
named phases in a fixed order (docs/tick.md):

  1. inputs   input neurons count down; one whose count reaches 0 spikes
  2. feed     new sensor values are latched by idle input neurons (latency floor(v) + 1)
              (1 and 2 run in one loop: each input neuron is independent of the others)
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
from numba import njit, prange

from .circuit import Circuit
from .stdp import stdp_table

HISTORY = 30  # arrivals a neuron remembers since its last spike (oldest dropped)
NEVER = -(2**62)  # last-spike tick of a neuron that has not fired yet
SYN_BITS = 16  # a history entry packs (arrival tick << SYN_BITS) | synapse index

# npar columns: per-neuron parameters (from its type), then W(dt) for dt = -STDP_OFFSET.. (stdp.py)
REST, THRESHOLD, DECAY, REFR_V, REFR_PERIOD, FLOOR, W_MIN, W_MAX, STDP_OFFSET, STDP = range(10)
# syn columns; flags bits
PRE, POST, DELAY, FLAGS = 0, 1, 2, 3
INHIBITORY, PLASTIC = 1, 2
# node state columns [A, nodes, 3]: for neurons ...
REFR_LEFT, LAST_SPIKE, HIST_LEN = 0, 1, 2
# ... and for input neurons (the nodes after the neurons)
COUNT, LEFT, LATENCY = 0, 1, 2
# inpar columns: per input neuron
PULSES, AT_START = 0, 1
# clock: [tick, training]
TICK, TRAINING = 0, 1


@njit(cache=True, inline="always")
def _learn(a, s, post, dt, npar, w):
    """STDP: w += W(dt) from the post neuron's table, clipped to [w_min, w_max]."""
    k = dt + int(npar[post, STDP_OFFSET])
    if 0 <= k < npar.shape[1] - STDP:
        w[a, s] = min(max(w[a, s] + npar[post, STDP + k], npar[post, W_MIN]), npar[post, W_MAX])


@njit(cache=True, inline="always")
def _step_agent(a, feed, clock, syn, npar, inpar, v, w, state, hist, ring, spiked):
    t = clock[TICK]
    training = clock[TRAINING] != 0
    n_neurons = v.shape[1]
    mask = ring.shape[1] - 1  # ring length is a power of two

    for i in range(feed.shape[1]):
        node = n_neurons + i
        spiked[a, node] = 0
        # 1. inputs: count down; a pulse when the count reaches 0, then restart for the next pulse
        if state[a, node, LEFT] > 0:
            state[a, node, COUNT] -= 1
            if state[a, node, COUNT] == 0:
                spiked[a, node] = 1
                state[a, node, LEFT] -= 1
                if state[a, node, LEFT] > 0:
                    state[a, node, COUNT] = state[a, node, LATENCY]
        # 2. feed: an idle input neuron latches a value x >= 0 (NaN: nothing fed); busy ones ignore it
        x = feed[a, i]
        feed[a, i] = np.nan  # consumed
        if t == 0 and not math.isnan(inpar[i, AT_START]):
            x = inpar[i, AT_START]
        if state[a, node, LEFT] == 0 and x >= 0.0 and x < 1e9:  # NaN and inf fail both tests
            latency = int(math.floor(x)) + 1
            state[a, node, LATENCY] = latency
            state[a, node, COUNT] = latency
            state[a, node, LEFT] = int(inpar[i, PULSES])

    # 3. deliver: pulses due now; a REFRACTORY post ignores them but they still count for learning.
    # Arrivals are random, so the potential update is branch-free: w * r * open is exactly 0 or w.
    slot = t & mask
    for s in range(syn.shape[0]):
        r = ring[a, slot, s]
        ring[a, slot, s] = 0
        post = syn[s, POST]
        dv = w[a, s] * r * (state[a, post, REFR_LEFT] == 0)
        if syn[s, FLAGS] & INHIBITORY:
            v[a, post] = max(v[a, post] - dv, npar[post, FLOOR])  # v >= floor always holds
        else:
            v[a, post] += dv
        if r and syn[s, FLAGS] & PLASTIC:
            last = state[a, post, LAST_SPIKE]
            if training and last != NEVER:  # once per pulse, against the latest post spike
                _learn(a, s, post, t - last, npar, w)
            n = state[a, post, HIST_LEN]
            if n == HISTORY:  # drop the oldest
                for h in range(HISTORY - 1):
                    hist[a, post, h] = hist[a, post, h + 1]
                n -= 1
            hist[a, post, n] = (t << SYN_BITS) | s
            state[a, post, HIST_LEN] = n + 1

    # 4. fire: refractory clamp, fire at threshold, or decay toward rest (selects, not branches)
    for n in range(n_neurons):
        refractory = state[a, n, REFR_LEFT] > 0
        fire = not refractory and v[a, n] >= npar[n, THRESHOLD]
        decayed = v[a, n] + (npar[n, REST] - v[a, n]) * npar[n, DECAY]  # never overshoots: decay < 1
        v[a, n] = npar[n, REFR_V] if refractory or fire else decayed
        state[a, n, REFR_LEFT] = int(npar[n, REFR_PERIOD]) if fire else state[a, n, REFR_LEFT] - refractory
        spiked[a, n] = fire
        if fire:
            if training:  # every remembered arrival is paired with this spike
                for h in range(state[a, n, HIST_LEN]):
                    s = hist[a, n, h] & ((1 << SYN_BITS) - 1)
                    _learn(a, s, n, (hist[a, n, h] >> SYN_BITS) - t, npar, w)
            state[a, n, HIST_LEN] = 0
            state[a, n, LAST_SPIKE] = t

    # 5. emit: every synapse of a node that spiked schedules a pulse at t + delay. That slot is
    # empty (delivered and cleared ring-length ticks ago), so a plain store needs no branch.
    for s in range(syn.shape[0]):
        ring[a, (t + syn[s, DELAY]) & mask, s] = spiked[a, syn[s, PRE]]


@njit(cache=True)
def _step_serial(feed, clock, syn, npar, inpar, v, w, state, hist, ring, spiked):
    for a in range(v.shape[0]):
        _step_agent(a, feed, clock, syn, npar, inpar, v, w, state, hist, ring, spiked)
    clock[TICK] += 1


@njit(cache=True, parallel=True)
def _step_parallel(feed, clock, syn, npar, inpar, v, w, state, hist, ring, spiked):
    for a in prange(v.shape[0]):
        _step_agent(a, feed, clock, syn, npar, inpar, v, w, state, hist, ring, spiked)
    clock[TICK] += 1


PARALLEL_FROM = 256  # agents; below this, thread start-up costs more than it saves


class Engine:
    """A agents of one circuit (same synapses, independent potentials, pulses and weights).

    Per tick: write sensor values into `feed` (shape [A, inputs], NaN = nothing fed), call
    `step()`, read `spiked` ([A, nodes]: neurons then input neurons), `v` and `w`.
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
        self.feed = np.full((A, I), np.nan)
        self.clock = np.zeros(2, dtype=np.int64)
        self.v = np.empty((A, N))
        self.w = np.empty((A, S))
        self.state = np.empty((A, N + I, 3), dtype=np.int64)
        self.hist = np.zeros((A, N, HISTORY), dtype=np.int64)
        self.ring = np.empty((A, ring_len, S), dtype=np.uint8)
        self._spiked = np.zeros((A, N + I), dtype=np.uint8)
        self.spiked = self._spiked.view(np.bool_)
        self._call = _step_parallel if agents >= PARALLEL_FROM else _step_serial
        self._args = (self.feed, self.clock, self.syn, self.npar, self.inpar, self.v, self.w,
                      self.state, self.hist, self.ring, self._spiked)
        self.training = training
        self.reset()

    def reset(self) -> None:
        """Back to tick 0: potentials at rest, initial weights, nothing in flight."""
        self.clock[TICK] = 0
        self.feed[:] = np.nan
        N = self.n_neurons
        self.v[:] = self.npar[:, REST]
        self.w[:] = self.initial_weights
        self.state[:] = 0
        self.state[:, :N, LAST_SPIKE] = NEVER
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
        """Run one tick. `feed` (optional, [A, inputs]) is copied into self.feed first.

        Returns `spiked`, a bool view [A, nodes] that the next step overwrites.
        """
        if feed is not None:
            self.set_feed(feed)
        self._call(*self._args)
        return self.spiked

    def set_feed(self, feed) -> None:
        feed = np.asarray(feed, dtype=np.float64)
        if feed.shape != self.feed.shape:
            raise ValueError(f"feed must have shape {self.feed.shape} (agents, inputs), got {feed.shape}")
        self.feed[:] = feed

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
