"""The robot's regime: does the simulated EV3 collide less as its free-running brain learns?

The paper trained the EV3 with A+ = A- = 0.08 (the simulation: 0.01-0.04) because its link ran
at about 50 iterations a second. Here the gateway drives the simulated EV3 in real time (30 cm
squares, a 15 cm object in the centre of each black and red one, 20 cm/s, 50 deg/s) and the brain
ticks at 1,000 Hz over the bus. A collision is the paper's: the ultrasonic distance falls below
5 cm (its onset). Conditions: learning at A = 0.08 and at the simulation's 0.02, and the same
brain with learning off (its reflexes only). Two runs at a time, one pair of processes per core.

Writes OUT/robot.json, robot.md (collisions per minute in each --bin seconds, and seconds in
contact) and robot.png (collisions so far against time, a line per run); the last line printed
is JSON. Run: `spikinglab bench robot`.
"""

from __future__ import annotations

import json
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from services.launch import local_endpoints, spawn, stop
from services.options import Parser, at_least, output_folder, positive

CONDITIONS = {  # name -> brain options
    "learning, A = 0.08 (the paper's robot)": ["--a-plus", 0.08],
    "learning, A = 0.02 (the simulation's default)": ["--a-plus", 0.02],
    "no learning (reflexes only)": ["--no-training"],
}


def one_run(brain_options: list, seed: int, seconds: float, gateway_options: list) -> dict:
    """One simulated EV3 and its brain for `seconds`; the gateway's stats."""
    with tempfile.TemporaryDirectory() as tmp:
        (gateway_ep,), sockets = local_endpoints("gateway")
        with sockets:
            stats = Path(tmp) / "gateway.json"
            gateway = spawn(
                "gateway",
                [
                    "--backend",
                    "sim",
                    "--sim-seed",
                    seed,
                    "--listen",
                    gateway_ep,
                    "--duration",
                    seconds,
                    "--stats",
                    stats,
                    *gateway_options,
                ],
                Path(tmp) / "gateway.log",
            )
            brain = spawn(
                "brain",
                ["--connect", gateway_ep, "--clock", 1000, "--seed", seed, *brain_options],
                Path(tmp) / "brain.log",
            )
            try:
                gateway.wait(seconds + 60)
            finally:
                stop(brain)
                stop(gateway)
            return json.loads(stats.read_text())


def per_bin(collisions: list, seconds: float, bin_s: float) -> np.ndarray:
    """Collisions (their onsets) in each bin of bin_s seconds."""
    return np.histogram([start for start, _ in collisions], bins=np.arange(0, seconds + 1e-9, bin_s))[0]


def contact_s(collisions: list) -> float:
    return sum(end - start for start, end in collisions)


def plot(results: dict, seconds: float, out: Path) -> None:
    """Cumulative collisions over time, a line per run: learning shows as the line flattening."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    for (name, runs), colour in zip(results.items(), ("tab:green", "tab:orange", "tab:gray")):
        for k, r in enumerate(runs):
            starts = [0.0] + [start for start, _ in r["collisions"]] + [seconds]
            counts = list(range(len(starts) - 1)) + [len(starts) - 2]
            ax.step(starts, counts, where="post", color=colour, lw=1.5, label=name if k == 0 else None)
    ax.set(
        xlabel="seconds of real time (1,000 brain ticks a second)",
        ylabel="collisions so far",
        title="Simulated EV3: collisions (ultrasonic < 5 cm), a line per seed",
    )
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def parser() -> Parser:
    p = Parser(prog="spikinglab bench robot", description=(__doc__ or "").partition("\n\n")[0])
    p.add_argument("--seconds", type=positive, default=120, help="real time per run (default 120)")
    p.add_argument("--seeds", type=at_least(1), default=3, help="runs per condition (default 3)")
    p.add_argument("--bin", type=positive, default=30, help="seconds per column of the table (default 30)")
    p.add_argument(
        "--spin-ms", type=at_least(1), default=100, help="the gateway's spin per ROTATE (default 100: 5 degrees)"
    )
    p.add_argument(
        "--out", type=output_folder, default=Path("bench-results"), help="where the table goes (default bench-results)"
    )
    return p


def in_words(seconds: float) -> str:
    """A wait in seconds under a minute, in minutes beyond (10 s as minutes read "0 minutes")."""
    if round(seconds) < 60:
        return f"{seconds:.0f} second{'' if round(seconds) == 1 else 's'}"
    minutes = round(seconds / 60)
    return f"{minutes} minute{'' if minutes == 1 else 's'}"


def run_all(args) -> dict[str, list]:
    """Every condition's runs, two at a time, each said as it ends."""
    jobs = [(name, seed) for seed in range(args.seeds) for name in CONDITIONS]
    took = in_words((len(jobs) + 1) // 2 * args.seconds)
    print(f"{len(jobs)} runs of {args.seconds:.0f} s, two at a time: about {took}", flush=True)
    results: dict[str, list] = {name: [] for name in CONDITIONS}
    started = time.monotonic()
    with ThreadPoolExecutor(2) as pool:
        futures = {
            pool.submit(one_run, CONDITIONS[name], seed, args.seconds, ["--spin-ms", args.spin_ms]): (name, seed)
            for name, seed in jobs
        }
        for future, (name, seed) in futures.items():
            stats = future.result()
            results[name].append(stats)
            print(
                f"  [{time.monotonic() - started:5.0f} s] {name}, seed {seed}: {len(stats['collisions'])} "
                f"collisions, {contact_s(stats['collisions']):.1f} s in contact, {stats['commands']} motor commands",
                flush=True,
            )
    return results


def table_of(results: dict[str, list], args) -> tuple[str, dict]:
    """The collisions per minute of each condition, per column of --bin seconds: markdown, and figures."""
    bins = int(args.seconds // args.bin)
    rows = [
        "| condition | "
        + " | ".join(f"{k * args.bin:.0f}-{(k + 1) * args.bin:.0f} s" for k in range(bins))
        + " | all | seconds in contact |",
        "|---|" + "---|" * (bins + 2),
    ]
    summary = {}
    for name, runs in results.items():
        counts = np.array([per_bin(r["collisions"], args.seconds, args.bin) for r in runs]) * (60 / args.bin)
        mean = counts.mean(0)
        total = np.mean([len(r["collisions"]) for r in runs]) * 60 / args.seconds
        contact = np.mean([contact_s(r["collisions"]) for r in runs])
        rows.append(f"| {name} | " + " | ".join(f"{m:.0f}" for m in mean) + f" | {total:.1f} | {contact:.1f} |")
        summary[name] = {
            "per_minute": [round(float(m), 1) for m in mean],
            "all": round(float(total), 2),
            "contact_s": round(float(contact), 1),
        }
    table = (
        f"Collisions per minute (ultrasonic < 5 cm), mean over {args.seeds} seeds, "
        f"`spikinglab bench robot --seconds {args.seconds:g} --seeds {args.seeds} --bin {args.bin:g} "
        f"--spin-ms {args.spin_ms}`\n\n" + "\n".join(rows) + "\n"
    )
    return table, summary


def main(argv=None) -> dict:
    p = parser()
    args = p.parse_args(argv)
    if args.bin > args.seconds:  # the table would have no column
        p.error(f"argument --bin: {args.bin:g} s is longer than a run (--seconds {args.seconds:g})")
    args.out.mkdir(parents=True, exist_ok=True)
    results = run_all(args)
    table, summary = table_of(results, args)
    print(table)
    (args.out / "robot.md").write_text(table)
    (args.out / "robot.json").write_text(
        json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "runs": results, "summary": summary})
    )
    plot(results, args.seconds, args.out / "robot.png")
    print(f"wrote {args.out / 'robot.md'}, robot.json, robot.png")
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
