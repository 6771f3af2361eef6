"""Soak: a long run while each process's memory (RSS) is sampled and its slope printed.

Lock-step (default): world, brain and recorder as processes on a local bus (as `spikinglab run`
places them), while this process throws byte mutants of real messages of every kind at every key
(--fuzz-per-s in all); --ticks long. Robot (--robot): the free-running brain (--clock 1000) with the
gateway (ev3 backend) driving a fake brick, for --seconds. Each process's /proc/<pid>/status is
read every --sample-s; the slope is fitted over the second half of the run (after start-up and the
first compilations): flat memory is a slope near 0. The last line printed is JSON.
Run: `spikinglab bench soak [--ticks 1000000]` or `spikinglab bench soak --robot [--seconds 600]`.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from services.bus.config import session_for
from services.bus.schemas import encode
from services.launch import local_endpoints, spawn
from services.options import Parser, at_least, output_folder, positive

from .fuzz import KEY_OF, examples
from .gateway import gateway_and_brain


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def fuzz(endpoints: list[str], per_s: float, stop: threading.Event, counts: dict) -> None:
    """Byte mutants of a real message of every kind, at its key, `per_s` in all."""
    rng = np.random.default_rng(0)
    originals = [(KEY_OF[type(m)].replace("insect", "soak"), encode(m)) for m in examples()]
    with session_for(connect=endpoints) as session:
        publishers = {key: session.declare_publisher(key) for key, _ in originals}
        while not stop.wait(1 / per_s):
            key, data = originals[rng.integers(len(originals))]
            payload = bytearray(data)
            for where in rng.integers(0, len(payload), rng.integers(1, 4)):
                payload[where] = rng.integers(0, 256)
            publishers[key].put(bytes(payload), attachment=b"soak fuzzer")
            counts["sent"] += 1


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench soak", description=(__doc__ or "").splitlines()[0])
    # each mode's options without defaults here (Parser.mode_defaults)
    p.add_argument(
        "--ticks", type=at_least(10_000), help="lock-step: the run's ticks (at least 10,000; default 1,000,000)"
    )
    p.add_argument(
        "--fuzz-per-s", type=positive, help="lock-step: malformed messages per second, all keys (default 200)"
    )
    p.add_argument("--robot", action="store_true", help="the free-running brain, gateway and fake brick instead")
    p.add_argument("--seconds", type=at_least(10), help="robot: how long the gateway runs (default 600)")
    p.add_argument("--clock", type=positive, help="robot: the brain's clock in Hz (default 1000)")
    p.add_argument("--sample-s", type=positive, default=2.0, help="how often RSS is read, in seconds (default 2)")
    p.add_argument(
        "--out",
        type=output_folder,
        help="keep the logs, metrics and recording here (default: a temporary folder)",
    )
    args = p.parse_args(argv)
    p.mode_defaults(
        args,
        "--robot" if args.robot else "",
        {
            "--ticks": (1_000_000, ("",)),
            "--fuzz-per-s": (200.0, ("",)),
            "--seconds": (600, ("--robot",)),
            "--clock": (1000.0, ("--robot",)),
        },
    )
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        result = robot_soak(args, out) if args.robot else lockstep_soak(args, out)
    print(json.dumps(result))
    return result


def lockstep_soak(args, out: Path) -> dict:
    """World, brain and recorder for --ticks, the fuzzer throwing at every key."""
    (world_ep, brain_ep), sockets = local_endpoints("world", "brain")
    group = ["--group", "soak"]
    with sockets:
        processes = {
            "world": spawn(
                "world",
                ["--listen", world_ep, "--ticks", args.ticks, "--publish-state", "--out", out, *group],
                out / "world.log",
            ),
            "brain": spawn(
                "brain",
                ["--listen", brain_ep, "--connect", world_ep, "--once", "--publish-state"]
                + ["--stats", out / "brain.json", *group],
                out / "brain.log",
            ),
            "recorder": spawn(
                "record",
                ["--connect", world_ep, "--connect", brain_ep, "--out", out / "soak.rrd", *group],
                out / "recorder.log",
            ),
        }
        stop, counts = threading.Event(), {"sent": 0}
        fuzzer = threading.Thread(target=fuzz, args=([world_ep, brain_ep], args.fuzz_per_s, stop, counts))
        try:
            # the fuzzer starts once the run has: on the plain bus the first map, layout or sensors set the
            # run that recorder and brain serve, a forged one too (docs/security.md: the secured bus stops that)
            while " run " not in (out / "world.log").read_text() or "brain for" not in (out / "brain.log").read_text():
                gone = {name: p.poll() for name, p in processes.items() if p.poll() is not None}
                if gone:  # one that ended before the run started would hold this wait for good
                    name = next(iter(gone))
                    raise SystemExit(f"the {name} ended before the run started (exit {gone[name]}): {out / name}.log")
                time.sleep(0.1)
            fuzzer.start()
            samples, wall = sample_until(processes, processes["world"], args.sample_s)
            ended(processes, {"world": 0, "brain": 60, "recorder": 120}, out / "world.log")
        finally:
            stop.set()
            if fuzzer.is_alive():
                fuzzer.join()
            stop_all(processes)
    metrics = json.loads((out / "metrics.json").read_text())
    ticks_per_s = metrics["ticks_per_s"]
    result = {
        "ticks": metrics["ticks"],
        "ticks_per_s": round(ticks_per_s),
        "fuzzed": counts["sent"],
        "rejected_by_world": sum(sum(r.values()) for r in metrics["rejected_messages"].values()),
    }
    for name, (slope, end) in slopes(samples, wall, 100_000 / ticks_per_s, "100,000 ticks").items():
        result[f"{name}_rss_mb_end"] = end
        result[f"{name}_rss_slope_mb_per_100k_ticks"] = round(slope, 3)
    print(
        f"{metrics['ticks']:,} ticks at {ticks_per_s:,.0f} ticks/s; {counts['sent']:,} malformed messages thrown, "
        f"{result['rejected_by_world']:,} of them at the world's inbox rejected; every process ended cleanly"
    )
    return result


def robot_soak(args, out: Path) -> dict:
    """The free-running brain driving the fake brick through the gateway for --seconds."""
    (gateway_ep, brain_ep), sockets = local_endpoints("gateway", "brain")
    group = ["--group", "soak"]
    with sockets:
        processes = {"fake-brick": spawn("fake-brick", [], out / "fake-brick.log")}
        processes["gateway"], processes["brain"] = gateway_and_brain(
            gateway_ep,
            brain_ep,
            args.clock,
            ["--duration", args.seconds, "--stats", out / "gateway.json", *group],
            ["--stats", out / "brain.json", *group],
            logs=out,
        )
        try:
            samples, wall = sample_until(processes, processes["gateway"], args.sample_s)
            ended(processes, {"gateway": 0, "brain": 60}, out / "gateway.log")
        finally:
            stop_all(processes)
    brain = json.loads((out / "brain.json").read_text())
    result = {key: brain[key] for key in ("ticks", "hz", "late_ms_median", "late_ms_p99", "late_ms_max")}
    for name, (slope, end) in slopes(samples, wall, 3600, "hour").items():
        result[f"{name.replace('-', '_')}_rss_mb_end"] = end
        result[f"{name.replace('-', '_')}_rss_slope_mb_per_hour"] = round(slope, 2)
    print(
        f"{brain['ticks']:,} brain ticks at {brain['hz']:,.1f} Hz over {wall:.0f} s; lateness median "
        f"{brain['late_ms_median']} ms, p99 {brain['late_ms_p99']} ms, max {brain['late_ms_max']} ms"
    )
    return result


def sample_until(processes: dict, last, sample_s: float) -> tuple[list, float]:
    """Every process's RSS every `sample_s`, printed as it goes, until `last` ends: ([(seconds,
    {name: MB})], seconds in all)."""
    samples = []
    started = time.monotonic()
    while last.poll() is None:
        time.sleep(sample_s)
        at = time.monotonic() - started
        sample = {name: rss_mb(proc.pid) for name, proc in processes.items() if proc.poll() is None}
        if not sample:  # all ended during the sleep
            break
        samples.append((at, sample))
        print(f"{at:6.0f} s  " + "  ".join(f"{n} {mb:6.1f} MB" for n, mb in sample.items()), flush=True)
    return samples, time.monotonic() - started


def ended(processes: dict, waits: dict, log: Path) -> None:
    """Each of `waits` ended with 0 within its seconds (in order), or SystemExit with the codes and `log`."""
    if any(processes[name].wait(seconds or None) != 0 for name, seconds in waits.items()):
        codes = {name: proc.poll() for name, proc in processes.items()}
        raise SystemExit(f"a process failed: exit codes {codes}; {log}: {log.read_text()[-1500:]}")


def stop_all(processes: dict) -> None:
    for proc in processes.values():
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()


def slopes(samples: list, wall: float, seconds_per_unit: float, unit: str) -> dict:
    """Per process, fitted over the second half of the run: (MB per `unit`, MB at the end), each
    printed with the peak."""
    half = [(t, s) for t, s in samples if t > wall / 2]
    found = {}
    for name in dict.fromkeys(name for _, s in samples for name in s):
        t = np.array([t for t, s in half if name in s])
        mb = np.array([s[name] for _, s in half if name in s])
        if len(t) < 3:
            print(f"{name:10s} RSS: {len(t)} samples in the second half, too few for a slope (run longer)")
            continue
        slope = float(np.polyfit(t, mb, 1)[0]) * seconds_per_unit
        peak = max(s[name] for _, s in samples if name in s)
        print(
            f"{name:10s} RSS: {mb[0]:.1f} -> {mb[-1]:.1f} MB over the second half, slope {slope:+.3f} MB "
            f"per {unit}, peak {peak:.1f} MB"
        )
        found[name] = (slope, round(float(mb[-1]), 1))
    return found


if __name__ == "__main__":
    main()
