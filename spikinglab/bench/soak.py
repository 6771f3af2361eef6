"""Soak: a long lock-step run with the recorder, while a fuzzer throws malformed messages at every
key; each process's memory (RSS) is sampled and its slope printed.

world, brain and recorder are processes on a local bus (as `spikinglab run` places them); this
process throws byte mutants of real messages of every kind at every key (--fuzz-per-s in all) and
reads /proc/<pid>/status every --sample-s. The slope is fitted over the second half of the run
(after start-up and the first compilations): flat memory is a slope near 0 MB per 100,000 ticks.
The last line printed is JSON. Run: `spikinglab bench soak [--ticks 1000000]`.
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from services.bus.config import make_config
from services.bus.schemas import encode
from services.launch import local_endpoints, spawn
from services.options import Parser, at_least, positive

from .fuzz import EXAMPLES, KEY_OF


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def fuzz(endpoints: list[str], per_s: float, stop: threading.Event, counts: dict) -> None:
    """Byte mutants of a real message of every kind, at its key, `per_s` in all."""
    rng = np.random.default_rng(0)
    originals = [(KEY_OF[type(m)].replace("insect", "soak"), encode(m)) for m in EXAMPLES]
    with zenoh.open(make_config(connect=endpoints)) as session:
        publishers = {key: session.declare_publisher(key) for key, _ in originals}
        while not stop.wait(1 / per_s):
            key, data = originals[rng.integers(len(originals))]
            payload = bytearray(data)
            for where in rng.integers(0, len(payload), rng.integers(1, 4)):
                payload[where] = rng.integers(0, 256)
            publishers[key].put(bytes(payload), attachment=b"soak fuzzer")
            counts["sent"] += 1


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench soak", description=__doc__.splitlines()[0])
    p.add_argument("--ticks", type=at_least(10_000), default=1_000_000)
    p.add_argument("--fuzz-per-s", type=positive, default=200.0, help="malformed messages per second, all keys")
    p.add_argument("--sample-s", type=positive, default=2.0, help="how often RSS is read")
    p.add_argument("--out", type=Path, help="keep the logs, metrics and recording here (default: a temporary folder)")
    args = p.parse_args(argv)
    (world_ep, brain_ep), sockets = local_endpoints("world", "brain")
    with sockets, tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        group = ["--group", "soak"]
        world = spawn(
            "world",
            ["--listen", world_ep, "--ticks", args.ticks, "--publish-state", "--out", out, *group],
            out / "world.log",
        )
        brain = spawn(
            "brain",
            [
                "--listen",
                brain_ep,
                "--connect",
                world_ep,
                "--once",
                "--publish-state",
                "--stats",
                out / "brain.json",
                *group,
            ],
            out / "brain.log",
        )
        recorder = spawn(
            "record",
            ["--connect", world_ep, "--connect", brain_ep, "--out", out / "soak.rrd", *group],
            out / "recorder.log",
        )
        processes = {"world": world, "brain": brain, "recorder": recorder}
        stop, counts = threading.Event(), {"sent": 0}
        # the fuzzer starts once the run has: on the plain bus the first map, layout or sensors set the
        # run that recorder and brain serve, a forged one too (docs/security.md: the secured bus stops that)
        while " run " not in (out / "world.log").read_text() or "brain for" not in (out / "brain.log").read_text():
            time.sleep(0.1)
        fuzzer = threading.Thread(target=fuzz, args=([world_ep, brain_ep], args.fuzz_per_s, stop, counts))
        fuzzer.start()
        samples = []  # (seconds, {name: MB})
        started = time.monotonic()
        try:
            while world.poll() is None:
                time.sleep(args.sample_s)
                at = time.monotonic() - started
                sample = {name: rss_mb(proc.pid) for name, proc in processes.items() if proc.poll() is None}
                samples.append((at, sample))
                print(
                    f"\r{at:6.0f} s  " + "  ".join(f"{n} {mb:6.1f} MB" for n, mb in sample.items()), end="", flush=True
                )
            print()
            if world.returncode != 0 or brain.wait(60) != 0 or recorder.wait(120) != 0:
                raise SystemExit(
                    f"a process failed: exit codes {[p.returncode for p in processes.values()]}; "
                    f"logs: {(out / 'world.log').read_text()[-1500:]}"
                )
        finally:
            stop.set()
            fuzzer.join()
            for proc in processes.values():
                if proc.poll() is None:
                    proc.kill()
        metrics = json.loads((out / "metrics.json").read_text())
        wall = time.monotonic() - started
    ticks_per_s = metrics["ticks_per_s"]
    result = {
        "ticks": metrics["ticks"],
        "ticks_per_s": round(ticks_per_s),
        "fuzzed": counts["sent"],
        "rejected_by_world": sum(sum(r.values()) for r in metrics["rejected_messages"].values()),
    }
    half = [(t, s) for t, s in samples if t > wall / 2]
    for name in processes:
        t = np.array([t for t, s in half if name in s])
        mb = np.array([s[name] for _, s in half if name in s])
        if len(t) < 3:
            continue
        per_s = np.polyfit(t, mb, 1)[0]
        per_100k = per_s / ticks_per_s * 100_000
        peak = max(s[name] for _, s in samples if name in s)
        print(
            f"{name:8s} RSS: {mb[0]:.1f} -> {mb[-1]:.1f} MB over the second half, slope {per_100k:+.3f} MB per "
            f"100,000 ticks, peak {peak:.1f} MB"
        )
        result[f"{name}_rss_mb_end"] = round(float(mb[-1]), 1)
        result[f"{name}_rss_slope_mb_per_100k_ticks"] = round(float(per_100k), 3)
    print(
        f"{metrics['ticks']:,} ticks at {ticks_per_s:,.0f} ticks/s; {counts['sent']:,} malformed messages thrown, "
        f"{result['rejected_by_world']:,} of them at the world's inbox rejected; every process ended cleanly"
    )
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
