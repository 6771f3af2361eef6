"""Sharded benchmark: agent-ticks/s of one population run as W world shards x M brain shards.

Each case starts a world (`--agents A --shards M`), or W world shards (`world --shard I/W`) on a
router, and M brain processes (`brain --shard I/M`) on a local bus; each brain shard's engine gets
cores / M threads and each world shard's kernels cores / W (at least one), and the world (the lead
shard: the slowest shard's) measures the lock-step rate from its first to its last tick.

Before the measured cases, two unmeasured ones as long as a case (the least W x M, then the most)
compile and cache every kernel the cases' processes use: which kernels a process picks depends on
its slice's size and on W > 1, and these two hold the largest and the smallest slices of each kind.
Then a bare Zenoh ping-pong between two processes is measured, as the bus's bound.

Prints the table: agent-ticks/s, the speed-up over the first case, and "of linear": that speed-up
over the growth in shards, (W + M) / (W + M of the first case), so 1.0 means each added shard
brought its full share. A row notes what bounds it where the benchmark can tell: more processes
(the shards, and the router where W > 1) than cores; ticks/s at least half the bare ping-pong's
round trips/s (a tick waits for at least one). The engine's share is not noted: it is not measured
here (`spikinglab bench engine`). The last line is JSON: {"agents": A, "cores": C, "shards":
{"M": agent_ticks_per_s, ...} (W = 1), "world_shards": {"W": {"M": agent_ticks_per_s, ...}, ...}}.
Process counts above the core count share cores, so measure where there are at least as many
cores as processes. Run:
`spikinglab bench scale [--agents 16000] [--shards 1 2 4 8] [--world-shards 1] [--ticks 200]`.

--links: only the links of the lock-step chain a tick waits on, in this process on one thread
(the world's sense and act, the engine's step, the sensors message encoded and decoded), in ms per
tick, with the message's size: what a shard of each kind divides.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numba

from services.brain.circuit import load_circuit
from services.bus.schemas import Array, Sensors, decode, encode
from services.launch import local_endpoints, spawn
from services.loop import brain_for, world_actions
from services.options import Parser, at_least
from services.world.world import SENSORS, World
from spikinglab.bench import steady_rate
from spikinglab.bench.loop import zenoh_roundtrips

NEAR = 0.5  # a rate at least this share of a bound's is noted as near that bound
ROUND_TRIPS = 2000  # of the bare ping-pong
WARM_UP = 20  # --links: ticks that compile the kernels, not measured


def sharded(agents: int, shards: int, ticks: int, worlds: int = 1) -> float:
    """Agent-ticks/s of one lock-step run with `shards` brain shards and `worlds` world shards."""
    cores = os.cpu_count() or 1
    endpoints, sockets = local_endpoints("hub", *(f"brain{i}" for i in range(shards)))
    world = ["--ticks", ticks, "--agents", agents, "--shards", shards]
    with sockets, tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "world.log"
        if worlds == 1:  # the world is the hub, as in `spikinglab run`
            hub = [spawn("world", ["--listen", endpoints[0], *world, "--out", tmp], log)]
        else:  # several world shards meet the brain shards at a router
            hub = [spawn("router", ["--listen", endpoints[0]], subprocess.DEVNULL)]
            hub += [
                spawn(
                    "world",
                    ["--connect", endpoints[0], *world, "--shard", f"{i}/{worlds}", "--out", tmp],
                    log if i == 1 else Path(tmp) / f"world{i}.log",
                    env={"NUMBA_NUM_THREADS": str(max(1, cores // worlds))},
                )
                for i in range(1, worlds + 1)
            ]
        brains = [
            spawn(
                "brain",
                ["--listen", endpoints[i + 1], "--connect", endpoints[0], "--once", "--shard", f"{i + 1}/{shards}"]
                + ["--world-shards", worlds],
                subprocess.DEVNULL,
                env={"NUMBA_NUM_THREADS": str(max(1, cores // shards))},
            )
            for i in range(shards)
        ]  # each shard's share of the cores
        ended = hub[1:] if worlds > 1 else hub
        try:
            if any(w.wait(1800) != 0 for w in ended) or any(b.wait(120) != 0 for b in brains):
                raise SystemExit(f"a shard or the world failed:\n{log.read_text()[-2000:]}")
        finally:
            for process in (*hub, *brains):
                process.kill()
        return steady_rate(Path(tmp)) * agents


def links(agents: int, ticks: int) -> dict:
    """Ms per tick of each link of the lock-step chain, on one thread, and the message's bytes."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        world = World(seed=1, agents=agents)
        brain = brain_for(world, load_circuit("insect"))
        seconds, size = {"world": 0.0, "engine": 0.0, "message": 0.0}, 0
        for tick in range(ticks + WARM_UP):
            t0 = time.perf_counter()
            values = world.sense()
            t1 = time.perf_counter()
            payload = encode(Sensors(tick=tick, names=SENSORS, values=Array.view(values), run="links"))
            decode(payload, Sensors)
            t2 = time.perf_counter()
            actions = brain.step(values)
            t3 = time.perf_counter()
            world.act(world_actions(brain.action_names, actions))
            if tick >= WARM_UP:
                seconds["world"] += t1 - t0 + time.perf_counter() - t3
                seconds["message"] += t2 - t1
                seconds["engine"] += t3 - t2
                size = len(payload)
    finally:
        numba.set_num_threads(threads)
    result = {f"{link}_ms": round(s / ticks * 1e3, 3) for link, s in seconds.items()} | {"message_bytes": size}
    print(
        f"A = {agents:,}, one thread, ms per tick: world (sense + act) {result['world_ms']:.2f}, engine "
        f"{result['engine_ms']:.2f}, sensors message encoded and decoded {result['message_ms']:.2f} "
        f"({size / 1e6:.2f} MB)"
    )
    return result


def bounds(worlds: int, shards: int, ticks_per_s: float, cores: int, round_trips: float) -> str:
    """The row's note: each bound the case is near or over, as measured, or ""."""
    processes = worlds + shards + (worlds > 1)  # the router relays where there are world shards
    notes = [f"{processes} processes on {cores} cores"] if processes > cores else []
    if ticks_per_s >= NEAR * round_trips:
        notes.append(f"bus: {ticks_per_s / round_trips:.0%} of the bare round trips/s")
    return f"  ({'; '.join(notes)})" if notes else ""


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench scale", description=(__doc__ or "").partition("\n\n")[0])
    p.add_argument("--agents", type=at_least(1), default=16_000, help="the population (default 16000)")
    # no defaults here (Parser.mode_defaults): --links takes neither
    p.add_argument("--shards", type=at_least(1), nargs="+", help="brain shards per case (default 1 2 4 8)")
    p.add_argument("--world-shards", type=at_least(1), nargs="+", help="world shards per case (default 1)")
    p.add_argument(
        "--ticks",
        type=at_least(2),
        default=200,
        help="lock-step ticks per case; the rate is after the first (default 200)",
    )
    p.add_argument("--links", action="store_true", help="only the chain's links in this process, one thread")
    args = p.parse_args(argv)
    p.mode_defaults(
        args, "--links" if args.links else "", {"--shards": ([1, 2, 4, 8], ("",)), "--world-shards": ([1], ("",))}
    )
    if args.links:
        result = links(args.agents, args.ticks)
        print(json.dumps(result))
        return result
    for option, counts in (("--shards", args.shards), ("--world-shards", args.world_shards)):
        if max(counts) > args.agents:
            p.error(f"argument {option}: {max(counts)} shards of {args.agents:,} agents: at most one shard per agent")
        if len(set(counts)) < len(counts):  # the JSON keeps one figure per count
            p.error(f"argument {option}: give each count once, got {' '.join(map(str, counts))}")
    cores = os.cpu_count() or 1
    print(f"A = {args.agents:,} agents, {args.ticks} lock-step ticks per case, {cores} cores")
    least, most = (min(args.world_shards), min(args.shards)), (max(args.world_shards), max(args.shards))
    warm_ups = dict.fromkeys((least, most))  # one where they are the same
    print(f"warm-up, unmeasured: {' and '.join(f'{w}x{n}' for w, n in warm_ups)}", flush=True)
    for w, n in warm_ups:
        sharded(args.agents, n, args.ticks, w)
    round_trips = zenoh_roundtrips(ROUND_TRIPS)
    print(f"bound: a bare Zenoh ping-pong, {round_trips:,.0f} round trips/s (a tick waits for one at least)")
    first = args.world_shards[0], args.shards[0]
    print(f"speed-up: over {first[0]}x{first[1]}; of linear: speed-up / ((W + M) / {sum(first)})", flush=True)
    print("world shards | brain shards | agent-ticks/s | speed-up | of linear")
    rates: dict[str, dict[str, int]] = {}
    for w in args.world_shards:
        for n in args.shards:
            rate = rates.setdefault(str(w), {})[str(n)] = round(sharded(args.agents, n, args.ticks, w))
            up = rate / rates[str(first[0])][str(first[1])]
            note = bounds(w, n, rate / args.agents, cores, round_trips)
            print(f"{w:12d} | {n:12d} | {rate:13,} | {up:8.2f} | {up / ((w + n) / sum(first)):9.2f}{note}", flush=True)
    result = {"agents": args.agents, "cores": cores, "shards": rates.get("1", {}), "world_shards": rates}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
