"""Sharded-brain benchmark: agent-ticks/s of one population whose brain runs as 1, 2, 4, 8 shards.

Each case starts a world (`--agents A --shards N`) and N brain processes (`brain --shard I/N`) on
a local bus; each shard's engine gets cores / N threads (at least one), and the world measures
the lock-step rate from its first to its last tick. Prints the scaling table (speed-up over one
shard, and that over N: 1.0 is linear) and, as its last line, JSON:
{"agents": A, "cores": C, "shards": {"1": agent_ticks_per_s, "2": ..., ...}}.
Shard counts above the core count share cores, so measure where there are at least as many cores
as shards. Run: `spikinglab bench scale [--agents 16000] [--shards 1 2 4 8] [--ticks 200]`.
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


def sharded(agents: int, shards: int, ticks: int) -> float:
    """Agent-ticks/s of one lock-step run with `shards` brain shards."""
    endpoints, sockets = local_endpoints("world", *(f"brain{i}" for i in range(shards)))
    threads = str(max(1, (os.cpu_count() or 1) // shards))
    with sockets, tempfile.TemporaryDirectory() as tmp:
        world = spawn(
            "world",
            ["--listen", endpoints[0], "--ticks", ticks, "--agents", agents, "--shards", shards, "--out", tmp],
            Path(tmp) / "world.log",
        )
        brains = [
            spawn(
                "brain",
                ["--listen", endpoints[i + 1], "--connect", endpoints[0], "--once", "--shard", f"{i + 1}/{shards}"],
                subprocess.DEVNULL,
                env={"NUMBA_NUM_THREADS": threads},
            )
            for i in range(shards)
        ]  # each shard's share of the cores
        try:
            if world.wait(1800) != 0 or any(b.wait(120) != 0 for b in brains):
                raise SystemExit(f"a shard or the world failed:\n{(Path(tmp) / 'world.log').read_text()[-2000:]}")
        finally:
            for process in (world, *brains):
                process.kill()
        return steady_rate(Path(tmp)) * agents


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench scale", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--agents", type=at_least(1), default=16_000)
    p.add_argument("--shards", type=at_least(1), nargs="+", default=[1, 2, 4, 8])
    p.add_argument("--ticks", type=at_least(1), default=200)
    args = p.parse_args(argv)
    cores = os.cpu_count() or 1
    print(f"A = {args.agents:,} agents, {args.ticks} lock-step ticks per case, {cores} cores")
    rates = {}
    print("shards | agent-ticks/s | speed-up | of linear")
    for n in args.shards:
        rates[str(n)] = round(sharded(args.agents, n, args.ticks))
        base = rates[str(args.shards[0])] / args.shards[0]
        up = rates[str(n)] / base
        print(
            f"{n:6d} | {rates[str(n)]:13,} | {up:8.2f} | {up / n:9.2f}"
            + ("  (more shards than cores)" if n > cores else ""),
            flush=True,
        )
    result = {"agents": args.agents, "cores": cores, "shards": rates}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
