"""Closed-loop benchmark: lock-step ticks/s of world + brain, and the bounds it is measured against.

All figures in one run, on this machine:
  zenoh:      a bare Zenoh ping-pong between two processes placed as world and brain are (the
              lock-step loop's bound: one round trip per tick)
  inprocess:  world and brain in this process, 1 agent (the fused loop) and A = 1000
  engine:     the engine alone at A = 1000 on random feeds (the in-process loop's bound)
  bus:        world and brain as two processes on a local Zenoh bus (Unix sockets, one CPU each,
              as `spikinglab run` places them), 1 agent, A = 1000 and A = 16000
  recording:  the 1-agent lock-step loop with both publishing state to a recorder (run in turns
              with the unrecorded one)
The bus figures are the world's own, after its first tick: that round trip holds the brain's
start (its network built, compiled code loaded: 0.1-0.2 s), which the in-process loop and the
ping-pong leave out as a warm-up too.
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

from services.brain.circuit import load_circuit
from services.brain.engine import DEFAULT_SEMANTICS, PARALLEL_FROM, SEMANTICS, Engine
from services.launch import local_endpoints, spawn
from services.loop import brain_for, closed_loop
from services.options import Parser, at_least
from services.world.world import World
from spikinglab.bench import steady_rate
from spikinglab.bench.engine import best_rate
from spikinglab.bench.feeds import random_feeds
from spikinglab.bench.recorder import one_run


def inprocess(ticks: int, semantics: str, agents: int = 1) -> float:
    """Agent-ticks/s of the closed loop in this process."""
    world = World(seed=1, agents=agents)
    brain = brain_for(world, load_circuit("insect"), semantics=semantics)
    closed_loop(world, brain, 200)  # compile and warm up
    started = time.perf_counter()
    closed_loop(world, brain, ticks)
    return ticks * agents / (time.perf_counter() - started)


def engine_alone(ticks: int, semantics: str, agents: int) -> float:
    """Agent-ticks/s of the engine alone on random feeds (best of 3 passes)."""
    circuit = load_circuit("insect")
    engine = Engine(circuit, agents=agents, semantics=semantics)
    return best_rate(engine, random_feeds(np.random.default_rng(0), circuit, ticks, agents), 3, agents)


def pins(wanted: bool) -> list[list[str]]:
    """--cpu options for the two processes of a round trip, on cores 0 and 1 where there are two."""
    return [["--cpu", "0"], ["--cpu", "1"]] if wanted and (os.cpu_count() or 1) >= 2 else [[], []]


def zenoh_roundtrips(count: int) -> float:
    """Round trips/s of a bare Zenoh ping-pong, the two processes placed as world and brain."""
    (pong_ep,), sockets = local_endpoints("pong")  # ping connects to pong
    with sockets, tempfile.TemporaryDirectory() as tmp:
        pin = pins(True)
        out = Path(tmp) / "ping.log"
        pong = spawn("services.bus.pingpong", ["pong", "--listen", pong_ep] + pin[1], subprocess.DEVNULL)
        try:
            ping = spawn("services.bus.pingpong", ["ping", "--connect", pong_ep, "--count", count] + pin[0], out)
            if ping.wait(300) != 0:
                raise SystemExit(f"the ping-pong failed: {out.read_text()[-500:]}")
        finally:
            pong.kill()
            pong.wait()
        figure = [line for line in out.read_text().splitlines() if line.startswith("{")][-1]  # its log lines too
        return json.loads(figure)["roundtrips_per_s"]


def over_the_bus(ticks: int, agents: int, semantics: str) -> float:
    """Ticks/s measured by the world process itself, after the first tick (bench.steady_rate)."""
    (world_ep, brain_ep), sockets = local_endpoints("world", "brain")
    with sockets, tempfile.TemporaryDirectory() as tmp:
        pin = pins(agents < PARALLEL_FROM)  # the parallel kernels use every core
        world = spawn(
            "world",
            ["--listen", world_ep, "--ticks", ticks, "--agents", agents, "--out", tmp] + pin[0],
            subprocess.DEVNULL,
        )
        brain = spawn(
            "brain",
            ["--listen", brain_ep, "--connect", world_ep, "--once", "--semantics", semantics] + pin[1],
            subprocess.DEVNULL,
        )
        if world.wait(600) != 0 or brain.wait(60) != 0:
            raise SystemExit("the world or the brain failed")
        return steady_rate(Path(tmp))


def recorded_run(ticks: int) -> float:
    """Ticks/s of the 1-agent lock-step loop with world and brain publishing state to a recorder."""
    with tempfile.TemporaryDirectory() as tmp:
        return one_run(ticks, True, Path(tmp))["ticks_per_s"]


def median_of(runs: list[float]) -> tuple[float, str]:
    runs = sorted(runs)
    return float(np.median(runs)), ", ".join(f"{r:,.0f}" for r in runs)


def parser() -> Parser:
    p = Parser(prog="spikinglab bench loop", description=(__doc__ or "").splitlines()[0])
    p.add_argument(
        "--ticks",
        type=at_least(2),
        default=20_000,
        help="ticks of the one-agent bus runs (rates are measured after the first; default 20,000)",
    )
    p.add_argument("--agents", type=at_least(1), default=1000, help="agents of the batch cases (default 1000)")
    p.add_argument(
        "--batch-ticks",
        type=at_least(8),
        default=2000,
        help="ticks of the batch over the bus (default 2000; a quarter of it in one process)",
    )
    p.add_argument("--large-agents", type=at_least(1), default=16_000, help="agents of the large case (default 16000)")
    p.add_argument("--large-ticks", type=at_least(2), default=300, help="ticks of the large case (default 300)")
    p.add_argument(
        "--repeats", type=at_least(1), default=3, help="runs of each bus case (default 3; the median is reported)"
    )
    p.add_argument(
        "--semantics",
        choices=SEMANTICS,
        default=DEFAULT_SEMANTICS,
        help=f"the brain's engine semantics (default {DEFAULT_SEMANTICS})",
    )
    return p


def main(argv=None) -> dict:
    args = parser().parse_args(argv)
    A, big = args.agents, args.large_agents
    print(f"engine semantics: {args.semantics}; {os.cpu_count()} cores")
    # this shared machine varies by 10-20 % from run to run: each bus case three times, the median
    pings, text = median_of([zenoh_roundtrips(args.ticks) for _ in range(args.repeats)])
    print(f"bare Zenoh ping-pong, two processes on one CPU each: {pings:,.0f} round trips/s median (runs: {text})")
    rate = inprocess(args.ticks * 10, args.semantics)
    print(f"in one process, 1 agent (fused loop): {rate:,.0f} ticks/s")
    engine = engine_alone(args.batch_ticks // 4, args.semantics, A)
    batch_in = inprocess(args.batch_ticks // 4, args.semantics, A)
    print(
        f"A = {A}: engine alone {engine:,.0f} agent-ticks/s, the loop in one process {batch_in:,.0f} "
        f"({batch_in / engine:.0%} of the engine)"
    )
    # unrecorded and recorded in turns: the machine drifts more between minutes than the recording costs
    turns = [(over_the_bus(args.ticks, 1, args.semantics), recorded_run(args.ticks)) for _ in range(args.repeats)]
    bus, text = median_of([plain for plain, _ in turns])
    print(
        f"two processes on the bus, 1 agent: {bus:,.0f} ticks/s median ({1e6 / bus:.0f} us per lock-step "
        f"round trip, {bus / pings:.0%} of the bare ping-pong; runs: {text})"
    )
    batch, text = median_of([over_the_bus(args.batch_ticks, A, args.semantics) * A for _ in range(args.repeats)])
    print(
        f"two processes on the bus, A = {A}: {batch:,.0f} agent-ticks/s median ({batch / batch_in:.0%} of the loop "
        f"in one process; runs: {text})"
    )
    large_in = inprocess(args.large_ticks, args.semantics, big)
    large, text = median_of([over_the_bus(args.large_ticks, big, args.semantics) * big for _ in range(args.repeats)])
    print(
        f"A = {big}: in one process {large_in:,.0f} agent-ticks/s, two processes on the bus {large:,.0f} median "
        f"({large / large_in:.0%}; runs: {text})"
    )
    recorded, text = median_of([recorded for _, recorded in turns])
    print(
        f"two processes on the bus, 1 agent, recorded: {recorded:,.0f} ticks/s median ({abs(1 - recorded / bus):.0%} "
        f"{'below' if recorded <= bus else 'above'} the loop unrecorded; runs: {text})"
    )
    result = {
        "zenoh_roundtrips_per_s": round(pings),
        "inprocess_ticks_per_s": round(rate),
        "bus_ticks_per_s": round(bus),
        f"engine_batch{A}_agent_ticks_per_s": round(engine),
        f"inprocess_batch{A}_agent_ticks_per_s": round(batch_in),
        f"bus_batch{A}_agent_ticks_per_s": round(batch),
        f"inprocess_batch{big}_agent_ticks_per_s": round(large_in),
        f"bus_batch{big}_agent_ticks_per_s": round(large),
        "recording_ticks_per_s": round(recorded),
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
