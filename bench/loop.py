"""Closed-loop benchmark: lock-step ticks/s of world + brain.

inprocess: one agent, world and brain in this process (no bus).
bus:       one agent, world and brain as two processes on a local Zenoh bus (Unix sockets, one
           CPU each, as `spikinglab run` places them).
batch:     A = 1000 agents in one message per tick, across the same two processes.
All with the default engine semantics, or `--semantics phased|netlogo`.
The last line printed is JSON. Run: `spikinglab bench loop` or `python -m spikinglab.bench.loop`.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from spikinglab.brain.circuit import load_circuit
from spikinglab.brain.engine import DEFAULT_SEMANTICS, PARALLEL_FROM, SEMANTICS
from spikinglab.launch import local_endpoints, spawn
from spikinglab.loop import brain_for, closed_loop
from spikinglab.options import Parser
from spikinglab.world.world import World


def inprocess(ticks: int, semantics: str) -> float:
    world = World(seed=1)
    brain = brain_for(world, load_circuit("insect"), semantics=semantics)
    closed_loop(world, brain, 200)  # compile and warm up
    started = time.perf_counter()
    closed_loop(world, brain, ticks)
    return ticks / (time.perf_counter() - started)


def over_the_bus(ticks: int, agents: int, semantics: str) -> float:
    """Ticks/s measured by the world process itself (from its first to its last tick)."""
    (world_ep, brain_ep), sockets = local_endpoints("world", "brain")
    with sockets, tempfile.TemporaryDirectory() as tmp:
        pin = ([["--cpu", "0"], ["--cpu", "1"]] if agents < PARALLEL_FROM and os.cpu_count() >= 2 else [[], []])
        world = spawn("world", ["--listen", world_ep, "--ticks", ticks, "--agents", agents, "--out", tmp] + pin[0],
                      subprocess.DEVNULL)
        brain = spawn("brain", ["--listen", brain_ep, "--connect", world_ep, "--once", "--semantics", semantics]
                      + pin[1], subprocess.DEVNULL)
        if world.wait(600) != 0 or brain.wait(60) != 0:
            raise SystemExit("the world or the brain failed")
        return json.loads((Path(tmp) / "metrics.json").read_text())["ticks_per_s"]


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench loop", description=__doc__.splitlines()[0])
    p.add_argument("--ticks", type=int, default=20_000, help="ticks of the one-agent runs")
    p.add_argument("--agents", type=int, default=1000)
    p.add_argument("--batch-ticks", type=int, default=2000)
    p.add_argument("--repeats", type=int, default=3, help="runs of each bus case (default 3; the median is reported)")
    p.add_argument("--semantics", choices=SEMANTICS, default=DEFAULT_SEMANTICS, help="the brain's engine semantics")
    args = p.parse_args(argv)
    print(f"engine semantics: {args.semantics}")
    rate = inprocess(args.ticks * 5, args.semantics)
    print(f"in one process, 1 agent: {rate:,.0f} ticks/s")
    # this shared 2-core machine varies by 10-20 % from run to run: three runs, their median
    runs = sorted(over_the_bus(args.ticks, 1, args.semantics) for _ in range(args.repeats))
    bus = float(np.median(runs))
    print(f"two processes on the bus, 1 agent: {bus:,.0f} ticks/s median ({1e6 / bus:.0f} us per lock-step "
          f"round trip; runs: {', '.join(f'{r:,.0f}' for r in runs)})")
    runs = sorted(over_the_bus(args.batch_ticks, args.agents, args.semantics) * args.agents for _ in range(args.repeats))
    batch = float(np.median(runs))
    print(f"two processes on the bus, {args.agents} agents: {batch:,.0f} agent-ticks/s median "
          f"(runs: {', '.join(f'{r:,.0f}' for r in runs)})")
    result = {"inprocess_ticks_per_s": round(rate), "bus_ticks_per_s": round(bus),
              f"bus_batch{args.agents}_agent_ticks_per_s": round(batch)}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
