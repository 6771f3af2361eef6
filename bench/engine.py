"""Engine benchmark: the insect circuit, random sensor input, training on.

single: ticks/s of one agent through Engine.step(feed), the per-tick call a closed loop makes.
batch:  agent-ticks/s of A = 1000 agents stepped together.
The last line printed is JSON. Run: `spikinglab bench engine` or `python -m bench.engine`.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from services.brain.circuit import load_circuit
from services.brain.engine import Engine

FEED_PROBABILITY = 0.3  # chance per tick that a sensor feeds its input neuron a value in [0, 4)


def random_feeds(rng, circuit, ticks, agents):
    """Random sensor values for the sensor-bound inputs only (the pacemaker kick stays the circuit's)."""
    feeds = np.full((ticks, agents, len(circuit.inputs)), np.nan)
    cols = list(circuit.sensors.values())
    shape = (ticks, agents, len(cols))
    feeds[:, :, cols] = np.where(rng.random(shape) < FEED_PROBABILITY, rng.random(shape) * 4.0, np.nan)
    return feeds


def best_rate(engine, feeds, repeats, agents=1):
    """Best of `repeats` passes over `feeds` in agent-ticks per second (first pass warms up)."""
    step = engine.step
    rates = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        for f in feeds:
            step(f)
        rates.append(len(feeds) * agents / (time.perf_counter() - t0))
    return max(rates[1:])


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(prog="spikinglab bench engine", description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=200_000, help="ticks per pass for one agent")
    parser.add_argument("--agents", type=int, default=1000, help="agents in the batch case")
    parser.add_argument("--batch-ticks", type=int, default=500, help="ticks per pass in the batch case")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)

    circuit = load_circuit("insect").with_learning_rate(0.04)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    single = Engine(circuit)
    single.step()
    batch = Engine(circuit, agents=args.agents)
    batch.step()
    print(f"compile/load: {time.perf_counter() - t0:.2f} s (cached after the first run)")

    feeds = random_feeds(rng, circuit, args.ticks, 1)
    single_rate = best_rate(single, feeds, args.repeats)
    print(f"single agent: {single_rate:,.0f} ticks/s ({1e6 / single_rate:.2f} us per step)")

    feeds = random_feeds(rng, circuit, args.batch_ticks, args.agents)
    batch_rate = best_rate(batch, feeds, args.repeats, agents=args.agents)
    print(f"A = {args.agents}: {batch_rate:,.0f} agent-ticks/s on {os.cpu_count()} cores")
    spikes = int(batch.run(feeds[:100]).sum())
    print(f"(spikes per agent per tick: {spikes / args.agents / 100:.2f}; training on)")

    result = {"single_ticks_per_s": round(single_rate), f"batch{args.agents}_agent_ticks_per_s": round(batch_rate)}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
