"""GPU benchmark: agent-ticks/s of the fused closed loop on a CUDA device, and on this machine's CPU.

A population of A insects, each in its own arena (the world of seed 0, insects 0..A-1), the
default engine semantics or --semantics. Device (services/gpu.py): a warm-up of --warmup ticks
(compiles the kernel), then --ticks ticks timed, the copies to and from the device included.
CPU: the same population for --cpu-ticks ticks on the CPU path (services.loop.closed_loop; from
PARALLEL_FROM insects the kernels run on numba's threads on every core). Without a device it is
refused in one line saying why; under NUMBA_ENABLE_CUDASIM=1 it runs numba's simulator (a check of
the command, not a figure). Prints a table and, as its last line, JSON:
{"agents": A, "ticks": T, "semantics": S, "device": rate, "cpu": rate, "cores": C, "simulator": bool}.
Run: `spikinglab bench gpu [--agents 1000000] [--ticks 2000] [--cpu-ticks 200]`.
"""

from __future__ import annotations

import json
import os
import time

from numba import get_num_threads

from services.brain.engine import DEFAULT_SEMANTICS, SEMANTICS
from services.gpu import device_problem, fused_loop_cuda
from services.loop import closed_loop, population
from services.options import Parser, at_least


def device_rate(agents: int, ticks: int, warmup: int, semantics: str) -> float:
    """Agent-ticks/s of `ticks` ticks on the device, after `warmup` ticks that compile the kernel."""
    world, brain = population({}, range(agents), semantics=semantics)
    fused_loop_cuda(world, brain, warmup)
    started = time.perf_counter()
    fused_loop_cuda(world, brain, ticks)
    return agents * ticks / (time.perf_counter() - started)


def cpu_rate(agents: int, ticks: int, semantics: str) -> float:
    """Agent-ticks/s of the same population on the CPU path, after one tick that compiles it."""
    world, brain = population({}, range(agents), semantics=semantics)
    closed_loop(world, brain, 1)
    started = time.perf_counter()
    closed_loop(world, brain, ticks)
    return agents * ticks / (time.perf_counter() - started)


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench gpu", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--agents", type=at_least(1), default=1_000_000)
    p.add_argument("--ticks", type=at_least(1), default=2000)
    p.add_argument("--warmup", type=at_least(1), default=10)
    p.add_argument("--cpu-ticks", type=at_least(1), default=200)
    p.add_argument("--semantics", choices=SEMANTICS, default=DEFAULT_SEMANTICS)
    args = p.parse_args(argv)
    problem = device_problem()
    if problem is not None:
        raise SystemExit(f"spikinglab bench gpu: refused: {problem}")
    simulator = os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0")
    print(
        f"A = {args.agents:,} insects, own arenas, {args.semantics} semantics" + (" (simulator)" if simulator else "")
    )
    rates = {
        "device": device_rate(args.agents, args.ticks, args.warmup, args.semantics),
        "cpu": cpu_rate(args.agents, args.cpu_ticks, args.semantics),
    }
    cores = get_num_threads()
    print("path   | ticks | agent-ticks/s")
    print(f"device | {args.ticks:5d} | {rates['device']:15,.0f}")
    print(f"cpu    | {args.cpu_ticks:5d} | {rates['cpu']:15,.0f}  ({cores} threads)")
    result = {"agents": args.agents, "ticks": args.ticks, "semantics": args.semantics, **rates}
    result |= {"cores": cores, "simulator": simulator}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
