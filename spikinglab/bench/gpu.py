"""GPU benchmark: agent-ticks/s of the fused closed loop on a CUDA device, and on this machine's CPU.

A population of A insects, each in its own arena (the world of seed 0, insects 0..A-1), the
default engine semantics or --semantics (and the netlogo semantics' --order), built once. Device
(services/gpu.py): a warm-up of --warmup ticks (compiles the kernel, or loads it from numba's
cache), then --ticks ticks timed, the copies to and from the device included. CPU: the same
population goes on for --cpu-ticks ticks on the CPU path (services.loop.closed_loop; from
PARALLEL_FROM insects the kernels run on numba's threads on every core). Without a device it is
refused in one line saying why; under NUMBA_ENABLE_CUDASIM=1 it runs numba's simulator (a check of
the command, not a figure). Prints each step's seconds, a table and, as its last line, JSON:
{"agents": A, "ticks": T, "semantics": S, "order": O, "device": rate, "cpu": rate, "registers": R,
"local_bytes": L, "cores": C, "simulator": bool} (registers and local memory per thread of the
kernel; not under the simulator).
Run: `spikinglab bench gpu [--agents 1000000] [--ticks 2000] [--cpu-ticks 200]`.
"""

from __future__ import annotations

import json
import time
from typing import Any

from numba import get_num_threads

from services.brain.engine import DEFAULT_SEMANTICS, SEMANTICS
from services.gpu import device_problem, fused_loop_cuda, simulated
from services.loop import closed_loop, population
from services.options import Parser, at_least


def measure(agents: int, ticks: int, warmup: int, cpu_ticks: int, semantics: str, order: str) -> dict:
    """One population, built once: `warmup` ticks on the device (they compile or load the kernel), `ticks`
    timed there, then one tick on the CPU path (it compiles) and `cpu_ticks` timed. Prints each step
    as it ends; the rates in agent-ticks/s, with the kernel's registers and local memory per thread."""
    started = time.perf_counter()
    world, brain = population({}, range(agents), semantics=semantics, order=order)
    step("built the population", started)
    started = time.perf_counter()
    fused_loop_cuda(world, brain, warmup)
    step(f"{warmup} ticks on the device, the kernel compiled or loaded from numba's cache", started)
    started = time.perf_counter()
    fused_loop_cuda(world, brain, ticks)
    device = agents * ticks / step(f"{ticks} ticks on the device", started)
    started = time.perf_counter()
    closed_loop(world, brain, 1)
    step("1 tick on the CPU, compiling its kernels", started)
    started = time.perf_counter()
    closed_loop(world, brain, cpu_ticks)
    cpu = agents * cpu_ticks / step(f"{cpu_ticks} ticks on the CPU", started)
    return {"device": device, "cpu": cpu, **kernel_resources()}


def step(what: str, started: float) -> float:
    seconds = time.perf_counter() - started
    print(f"  {what}: {seconds:.1f} s", flush=True)
    return seconds


def kernel_resources() -> dict:
    """Registers and local memory (spills, arrays) per thread of the compiled kernel; none under the
    simulator."""
    from services.gpu_kernels import fused_kernel

    kernel: Any = fused_kernel
    if not hasattr(kernel, "get_regs_per_thread"):  # the simulator's kernel
        return {}
    regs, local = kernel.get_regs_per_thread(), kernel.get_local_mem_per_thread()
    return {"registers": max(regs.values()), "local_bytes": max(local.values())}


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench gpu", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--agents", type=at_least(1), default=1_000_000, help="insects (default 1000000)")
    p.add_argument("--ticks", type=at_least(1), default=2000, help="ticks timed on the device (default 2000)")
    p.add_argument(
        "--warmup", type=at_least(1), default=10, help="device ticks before the timing: the compile (default 10)"
    )
    p.add_argument("--cpu-ticks", type=at_least(1), default=200, help="ticks timed on the CPU (default 200)")
    p.add_argument(
        "--semantics",
        choices=SEMANTICS,
        default=DEFAULT_SEMANTICS,
        help=f"the engine's semantics (default {DEFAULT_SEMANTICS})",
    )
    p.add_argument(
        "--order", choices=("random", "file"), default="random", help="the netlogo semantics' order (default random)"
    )
    args = p.parse_args(argv)
    if args.semantics == "phased" and args.order != "random":
        p.error("argument --order: the netlogo semantics' order; the phased semantics has none")
    problem = device_problem()
    if problem is not None:
        p.exit(2, f"{p.prog}: refused: {problem}\n")  # a device is what this benchmark measures
    simulator = simulated()
    order = f", {args.order} order" if args.semantics == "netlogo" else ""
    print(
        f"A = {args.agents:,} insects, own arenas, {args.semantics} semantics{order}"
        + (" (simulator)" if simulator else ""),
        flush=True,
    )
    rates = measure(args.agents, args.ticks, args.warmup, args.cpu_ticks, args.semantics, args.order)
    cores = get_num_threads()
    print("path   | ticks | agent-ticks/s")
    print(f"device | {args.ticks:5d} | {rates['device']:15,.0f}")
    print(f"cpu    | {args.cpu_ticks:5d} | {rates['cpu']:15,.0f}  ({cores} threads)")
    result = {"agents": args.agents, "ticks": args.ticks, "semantics": args.semantics, "order": args.order, **rates}
    result |= {"cores": cores, "simulator": simulator}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
