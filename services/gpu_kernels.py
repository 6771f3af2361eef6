"""The device side of services/gpu.py: the fused closed loop as one CUDA kernel, one thread per insect.

A port of the CPU path's per-agent code (services/world/world.py's sense, touch and act;
services/brain/engine.py's netlogo tick) to numba.cuda device functions on plain arrays:
docs/gpu.md says why a port and not calls into those kernels. The arrays keep the engine's layout
(agent axis last), so neighbouring threads read neighbouring words. tests/test_gpu.py holds the
port to the CPU path. Importing this module imports numba.cuda (the simulator under
NUMBA_ENABLE_CUDASIM=1).
"""

from __future__ import annotations

import math
from collections import namedtuple
from typing import Any

import numpy as np
from numba import cuda

from services.brain import build, engine
from services.brain.build import (
    AT_START,
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
    SYN_BITS,
    SYN_MASK,
    TABLE,
    THRESHOLD,
)
from services.gpu import simulated
from services.vocabulary import EMPTY, EV_ATE, EV_COLLISION, EV_LEARNED, EV_RESET
from services.world.world import (
    BIN,
    KERNEL_ARRAYS,
    LEARNED_AFTER,
    MOVE,
    PAIN,
    PAIN_VALUE,
    PUSH,
    RAY_STEP,
    REWARD,
    REWARD_VALUE,
    ROTATE,
    SMELL,
    START_X,
    START_Y,
    X_MIN,
    Y_MIN,
)

# The kernel's arrays in three named tuples: the world's (services.world.world.KERNEL_ARRAYS, but
# for `bin`: the collisions by bin from the launch's first, [bins, A]), the Network's and the
# State's (services/brain/build.py), with a scratch array for each insect's netlogo order.
DeviceWorld = namedtuple("DeviceWorld", KERNEL_ARRAYS)
DeviceNet = namedtuple(
    "DeviceNet", ["syn", "npar", "inpar", "stdp", "group", "profile", "out_start", "out_syn", "order_key"]
)
DeviceBrain = namedtuple("DeviceBrain", ["v", "w", "counters", "last_spike", "hist", "ring", "spiked", "order"])

device = cuda.jit(device=True)
# the engine's number-only helpers, their same Python compiled for the device
mix: Any = device(build.mix.py_func)
order_draw: Any = device(engine.order_draw.py_func)

if simulated():

    @device
    def mul(x, y):
        return x * y

else:  # a product rounded before the add that follows, as on the CPU: the device would fuse them (FMA)
    from numba.cuda.libdevice import dmul_rn as mul


@device
def colour_at(grid, g, x, y, fpar):
    ix = int(math.floor(x + 0.5)) - int(fpar[X_MIN])
    iy = int(math.floor(y + 0.5)) - int(fpar[Y_MIN])
    if ix < 0 or iy < 0 or ix >= grid.shape[1] or iy >= grid.shape[2]:
        return EMPTY, -1
    return grid[g, ix, iy], ix * grid.shape[2] + iy


@device
def sense_one(a, world, sensors, ray_steps):
    grid, pos, fpar, kind = world.grid, world.pos, world.fpar, world.kind
    g = world.arena_of[a]
    for k in range(sensors.shape[1]):
        sensors[a, k] = math.nan
    h = math.radians(world.heading[a])
    dx, dy = math.sin(h), math.cos(h)
    d = 0.0  # a running sum, as the CPU's and NetLogo's
    for _ in range(ray_steps):
        d += fpar[RAY_STEP]
        colour, _patch = colour_at(grid, g, pos[a, 0] + mul(d, dx), pos[a, 1] + mul(d, dy), fpar)
        if colour != EMPTY:
            sensors[a, SMELL[colour]] = d
            break
    colour, _patch = colour_at(grid, g, pos[a, 0], pos[a, 1], fpar)
    if kind[colour] == 1:
        sensors[a, PAIN] = fpar[PAIN_VALUE]
    elif kind[colour] == 2:
        sensors[a, REWARD] = fpar[REWARD_VALUE]


@device
def touch_one(a, t, training, world, bin_row):
    """The CPU's touch_range for insect a; world.bin holds the collisions by bin row, not the current bin's."""
    grid, pos, fpar, events, eaten, last_noxious = (
        world.grid,
        world.pos,
        world.fpar,
        world.events,
        world.eaten,
        world.last_noxious,
    )
    g = world.arena_of[a]
    for k in range(events.shape[1]):
        events[a, k] = 0
    eaten[a, 0] = -1
    eaten[a, 1] = -1
    colour, patch = colour_at(grid, g, pos[a, 0], pos[a, 1], fpar)
    if world.kind[colour] == 1:
        last_noxious[a] = t
        if patch != world.last_patch[a]:
            world.collisions[a] += 1
            world.collisions_by_colour[a, colour] += 1
            world.bin[bin_row, a] += 1
            world.last_collision[a] = t
            events[a, EV_COLLISION] = colour
        if training:
            h = math.radians(world.heading[a])
            pos[a, 0] += mul(fpar[PUSH], math.sin(h))
            pos[a, 1] += mul(fpar[PUSH], math.cos(h))
            world.distance[a] += fpar[PUSH]
    elif world.kind[colour] == 2:
        ix, iy = patch // grid.shape[2], patch % grid.shape[2]
        grid[g, ix, iy] = EMPTY
        eaten[a, 0] = ix
        eaten[a, 1] = iy
        world.food[a] += 1
        events[a, EV_ATE] = 1
    world.last_patch[a] = patch
    if world.learned_at[a] < 0 and t - max(last_noxious[a], 0) >= fpar[LEARNED_AFTER]:
        world.learned_at[a] = max(last_noxious[a], 0)
        events[a, EV_LEARNED] = 1


@device
def act_one(a, world):
    pos, heading, fpar, steps, actions = world.pos, world.heading, world.fpar, world.steps, world.actions
    if actions[a, ROTATE]:
        heading[a] = (heading[a] + steps[a, 0]) % 360.0
    if actions[a, MOVE]:
        h = math.radians(heading[a])
        pos[a, 0] += mul(steps[a, 1], math.sin(h))
        pos[a, 1] += mul(steps[a, 1], math.cos(h))
        world.distance[a] += steps[a, 1]
    x = pos[a, 0] - fpar[X_MIN]
    y = pos[a, 1] - fpar[Y_MIN]
    if x < 0.0 or y < 0.0 or x > world.grid.shape[1] - 1 or y > world.grid.shape[2] - 1:
        pos[a, 0] = fpar[START_X]
        pos[a, 1] = fpar[START_Y]
        world.resets[a] += 1
        world.events[a, EV_RESET] = 1


@device
def learn(w, s, a, post, dt, npar, stdp, group, profile):
    k = dt + int(npar[post, STDP_OFFSET])
    if 0 <= k < stdp.shape[2] - TABLE:
        g, p = group[a], profile[post]
        w[s, a] = min(max(w[s, a] + stdp[g, p, TABLE + k], stdp[g, p, LO]), stdp[g, p, HI])


@device
def feed_and_inputs(a, t, feed, inpar, syn, n_neurons, counters, ring, spiked):
    mask = ring.shape[0] - 1
    n_net = syn.shape[0] - feed.shape[1]
    for i in range(feed.shape[1]):
        node, s = n_neurons + i, n_net + i
        pulses = np.int32(inpar[i, PULSES])
        start = t == 0 and not math.isnan(inpar[i, AT_START])
        slot = (t + syn[s, DELAY]) & mask
        x = inpar[i, AT_START] if start else feed[a, i]
        left = counters[LEFT, node, a]
        take = left == 0 and x >= 0.0 and x < 1e9
        lat = np.int32(int(x) + 1) if take else counters[LATENCY, node, a]
        count = np.int32(0) if take else counters[COUNT, node, a]
        left = pulses if take else left
        if left > 0:
            count += 1
        fired = left > 0 and count == lat
        counters[LATENCY, node, a] = lat
        counters[COUNT, node, a] = 0 if fired else count
        counters[LEFT, node, a] = left - 1 if fired else left
        spiked[node, a] = 1 if fired else 0
        ring[slot, s, a] = 1 if fired else 0


@device
def receive(a, t, s, training, rules, syn, npar, lrn, v, w, counters, last_spike, hist):
    stdp, group, profile = lrn
    post = syn[s, POST]
    if counters[REFRACTORY, post, a] == 0:
        if syn[s, FLAGS] & INHIBITORY:
            v[post, a] = max(v[post, a] - w[s, a], npar[post, FLOOR])
        else:
            v[post, a] += w[s, a]
    if training and syn[s, FLAGS] & PLASTIC:
        n = counters[HIST_LEN, post, a]
        if n > HISTORY:
            for h in range(n - 1):
                hist[a, post, h] = hist[a, post, h + 1]
            n -= 1
        hist[a, post, n] = (t << SYN_BITS) | s
        counters[HIST_LEN, post, a] = n + 1
        last = last_spike[post, a]
        if rules & DT0_AGAIN:
            for h in range(n + 1):
                entry = hist[a, post, h]
                if (entry >> SYN_BITS) != last:
                    break
                learn(w, entry & SYN_MASK, a, post, 0, npar, stdp, group, profile)
            if t > last:
                learn(w, s, a, post, t - last, npar, stdp, group, profile)
        else:
            learn(w, s, a, post, t - last, npar, stdp, group, profile)


@device
def deliver(a, t, training, syn, npar, lrn, v, w, counters, last_spike, hist, ring):
    """Phased semantics, phase 3 (engine._deliver) for insect a."""
    stdp, group, profile = lrn
    slot = t & (ring.shape[0] - 1)
    for s in range(syn.shape[0]):
        post = syn[s, POST]
        dv = w[s, a] * ring[slot, s, a] * (counters[REFR_LEFT, post, a] == 0)  # exactly w or 0
        if syn[s, FLAGS] & INHIBITORY:
            v[post, a] = max(v[post, a] - dv, npar[post, FLOOR])
        else:
            v[post, a] += dv
        if syn[s, FLAGS] & PLASTIC and ring[slot, s, a] != 0:
            last = last_spike[post, a]
            if training and last != NEVER:
                learn(w, s, a, post, t - last, npar, stdp, group, profile)
            n = counters[HIST_LEN, post, a]
            if n == HISTORY:
                for h in range(HISTORY - 1):
                    hist[a, post, h] = hist[a, post, h + 1]
                n -= 1
            hist[a, post, n] = (t << SYN_BITS) | s
            counters[HIST_LEN, post, a] = n + 1
        ring[slot, s, a] = 0


@device
def fire(a, t, training, npar, lrn, v, w, counters, last_spike, hist, spiked):
    """Phased semantics, phase 4 (engine._fire) for insect a."""
    stdp, group, profile = lrn
    for n in range(v.shape[0]):
        refractory = counters[REFR_LEFT, n, a] > 0
        fires = not refractory and v[n, a] >= npar[n, THRESHOLD]
        decayed = v[n, a] + mul(npar[n, REST] - v[n, a], npar[n, DECAY])
        v[n, a] = npar[n, REFR_V] if refractory or fires else decayed
        if fires:
            counters[REFR_LEFT, n, a] = np.int32(npar[n, REFR_PERIOD])
            last_spike[n, a] = t
        elif refractory:
            counters[REFR_LEFT, n, a] -= 1
        spiked[n, a] = 1 if fires else 0
        if fires and counters[HIST_LEN, n, a] > 0:
            if training:
                for h in range(counters[HIST_LEN, n, a]):
                    entry = hist[a, n, h]
                    learn(w, entry & SYN_MASK, a, n, (entry >> SYN_BITS) - t, npar, stdp, group, profile)
            counters[HIST_LEN, n, a] = 0


@device
def phased_tick(a, t, training, feed, net, brain):
    """One phased tick (engine._step_range) for insect a: feed and inputs, deliver, fire, emit."""
    syn, npar, inpar, stdp, group, profile, out_start, out_syn, order_key = net
    v, w, counters, last_spike, hist, ring, spiked, order = brain
    lrn = (stdp, group, profile)
    feed_and_inputs(a, t, feed, inpar, syn, v.shape[0], counters, ring, spiked)
    deliver(a, t, training, syn, npar, lrn, v, w, counters, last_spike, hist, ring)
    fire(a, t, training, npar, lrn, v, w, counters, last_spike, hist, spiked)
    mask = ring.shape[0] - 1
    for s in range(syn.shape[0] - feed.shape[1]):  # emit: input neurons sent theirs in phase 2
        ring[(t + syn[s, DELAY]) & mask, s, a] = spiked[syn[s, PRE], a]


@device
def netlogo_tick(a, t, training, rules, feed, net, brain):
    syn, npar, inpar, stdp, group, profile, out_start, out_syn, order_key = net
    v, w, counters, last_spike, hist, ring, spiked, order = brain
    lrn = (stdp, group, profile)
    n_neurons = v.shape[0]
    feed_and_inputs(a, t, feed, inpar, syn, n_neurons, counters, ring, spiked)
    mask = ring.shape[0] - 1
    now = t & mask
    n_net = syn.shape[0] - feed.shape[1]
    send = 1 if rules & COUNT_FROM_SEND else 0
    if not rules & REOPEN_IN_TURN:
        for n in range(n_neurons):
            if counters[REFRACTORY, n, a] and counters[REFR_LEFT, n, a] <= 0:
                counters[REFRACTORY, n, a] = 0
    for s in range(n_net, syn.shape[0]):
        if ring[now, s, a]:
            ring[now, s, a] = 0
            post = syn[s, POST]
            if counters[REFRACTORY, post, a] == 0:
                v[post, a] += w[s, a]
    for n in range(n_neurons):
        order[n, a] = n
    if rules & SHUFFLE:  # the engine's Fisher-Yates from (agent seed, tick)
        r = mix(order_key[a] + np.uint64(t))
        for i in range(n_neurons - 1, 0, -1):
            r, j = order_draw(r, i)
            order[i, a], order[j, a] = order[j, a], order[i, a]
    for k in range(n_neurons):
        n = order[k, a]
        spiked[n, a] = 0
        if counters[REFRACTORY, n, a] == 0:
            if v[n, a] != npar[n, REST]:
                if v[n, a] >= npar[n, THRESHOLD]:
                    last_spike[n, a] = t
                    for h in range(counters[HIST_LEN, n, a]):
                        entry = hist[a, n, h]
                        learn(w, entry & SYN_MASK, a, n, (entry >> SYN_BITS) - t, npar, stdp, group, profile)
                    counters[HIST_LEN, n, a] = 0
                    for q in range(out_start[n], out_start[n + 1]):
                        s = out_syn[q]
                        ring[(t + syn[s, DELAY] - send) & mask, s, a] = 1
                    counters[REFRACTORY, n, a] = 1
                    counters[REFR_LEFT, n, a] = np.int32(npar[n, REFR_PERIOD])
                    spiked[n, a] = 1
                else:
                    v[n, a] += mul(npar[n, REST] - v[n, a], npar[n, DECAY])
        else:
            counters[REFR_LEFT, n, a] -= 1
            v[n, a] = npar[n, REFR_V]
            if counters[REFR_LEFT, n, a] <= 0 and rules & REOPEN_IN_TURN:
                counters[REFRACTORY, n, a] = 0
        for q in range(out_start[n], out_start[n + 1]):
            s = out_syn[q]
            if ring[now, s, a]:
                ring[now, s, a] = 0
                receive(a, t, s, training, rules, syn, npar, lrn, v, w, counters, last_spike, hist)


@cuda.jit(cache=True)  # the compiled kernel kept on disk, as the CPU kernels are
def fused_kernel(ticks, t0, tb0, bin0, flags, senses, drives, world, sensors, feed, net, brain, noxious):
    """`ticks` ticks of insect a = this thread: `world` a DeviceWorld, `senses` and `drives` as in
    services.loop's fused block, `net` a DeviceNet, `brain` a DeviceBrain, `noxious` [ticks, A]
    uint8 (or no rows: none kept): row k set to 1 where the pain sensor was fed in the launch's tick k."""
    a = cuda.grid(1)  # pyright: ignore[reportCallIssue] (numba's stub)
    if a >= world.pos.shape[0]:
        return
    ray_steps, world_training, brain_training, rules, netlogo = (
        flags[0],
        flags[1] != 0,
        flags[2] != 0,
        flags[3],
        flags[4] != 0,
    )
    spiked = brain.spiked
    for k in range(ticks):
        t = t0 + k
        sense_one(a, world, sensors, ray_steps)
        if noxious.shape[0] > 0:
            noxious[k, a] = sensors[a, PAIN] == sensors[a, PAIN]  # fed: not NaN
        for j in range(senses.shape[1]):
            feed[a, senses[1, j]] = sensors[a, senses[0, j]]
        if netlogo:
            netlogo_tick(a, tb0 + k, brain_training, rules, feed, net, brain)
        else:
            phased_tick(a, tb0 + k, brain_training, feed, net, brain)
        for j in range(drives.shape[1]):
            world.actions[a, drives[1, j]] = spiked[drives[0, j], a]
        touch_one(a, t, world_training, world, t // BIN - bin0)
        act_one(a, world)
