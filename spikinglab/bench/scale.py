"""Sharded benchmark: agent-ticks/s of one population whose brain runs as 1, 2, 4, 8 shards, and
whose world runs as 1 or more shards (`--world-shards`).

Each case starts a world (`--agents A --shards N`), or W world shards (`world --shard I/W`) on a
router, and N brain processes (`brain --shard I/N`) on a local bus; each brain shard's engine gets
cores / N threads and each world shard's kernels cores / W (at least one), and the world (the lead
shard: the slowest shard's) measures the lock-step rate from its first to its last tick. Prints
the scaling table (speed-up over one brain shard of the first case, and that over the brain shards:
1.0 is linear)
and, as its last line, JSON: {"agents": A, "cores": C, "shards": {"1": agent_ticks_per_s, ...}
(one world), "world_shards": {"W": {"N": agent_ticks_per_s, ...}, ...}}. Process counts above the
core count share cores, so measure where there are at least as many cores as processes. Run:
`spikinglab bench scale [--agents 16000] [--shards 1 2 4 8] [--world-shards 1 2] [--ticks 200]`.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

from services.launch import local_endpoints, spawn
from services.options import Parser, at_least
from spikinglab.bench import steady_rate


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


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench scale", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--agents", type=at_least(1), default=16_000)
    p.add_argument("--shards", type=at_least(1), nargs="+", default=[1, 2, 4, 8], help="brain shards per case")
    p.add_argument("--world-shards", type=at_least(1), nargs="+", default=[1], help="world shards per case")
    p.add_argument("--ticks", type=at_least(1), default=200)
    args = p.parse_args(argv)
    cores = os.cpu_count() or 1
    print(f"A = {args.agents:,} agents, {args.ticks} lock-step ticks per case, {cores} cores")
    rates: dict[str, dict[str, int]] = {}
    base = None
    print("world shards | brain shards | agent-ticks/s | speed-up | of linear")
    for w in args.world_shards:
        for n in args.shards:
            rate = rates.setdefault(str(w), {})[str(n)] = round(sharded(args.agents, n, args.ticks, w))
            base = base or rate / args.shards[0]  # per brain shard of the first case
            up = rate / base
            print(
                f"{w:12d} | {n:12d} | {rate:13,} | {up:8.2f} | {up / n:9.2f}"
                + ("  (more processes than cores)" if w + n > cores else ""),
                flush=True,
            )
    result = {"agents": args.agents, "cores": cores, "shards": rates.get("1", {}), "world_shards": rates}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
