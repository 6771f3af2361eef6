"""`spikinglab sweep`: the paper's Table 1 — learning time for symmetric A+ = A- over several seeds.

All seeds of one A+ value run as one population (one arena each) in one process, so a sweep takes
seconds. Writes runs/<id>/table.md, table.json and learning.png, and prints the table beside the
paper's numbers.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

import numpy as np

from services.brain.circuit import load_circuit
from services.loop import brain_for, closed_loop
from services.run import PAPER_TABLE_1
from services.world.world import PRESETS, World, params_for


def sweep_one(a_plus: float, seeds: int, ticks: int, preset: str, learned_after: int, progress=None) -> dict:
    world = World(params_for(preset, learned_after=learned_after), agents=seeds, seed=0)
    brain = brain_for(world, load_circuit("insect").with_learning_rate(a_plus))
    closed_loop(world, brain, ticks, (lambda t: progress.update(1)) if progress else None)
    bins = np.array(world.metrics.bins).T  # [seeds, ticks / 1000]
    q = bins.shape[1] // 4
    learned = [int(t) for t in world.metrics.learned_at if t >= 0]
    # not reached within the run counts as later than the run: a censored median, not a biased one
    times = np.where(world.metrics.learned_at >= 0, world.metrics.learned_at, np.inf)
    median, q1, q3 = np.median(times), *np.percentile(times, [25, 75])
    return {
        "a_plus": a_plus, "seeds": seeds, "ticks": ticks,
        "learning_time": [int(t) if t >= 0 else None for t in world.metrics.learned_at],
        "reached": len(learned),
        "median": float(median) if np.isfinite(median) else None,
        "quartiles": [float(x) if np.isfinite(x) else None for x in (q1, q3)],
        "collisions_first_quarter": bins[:, :q].sum(axis=1).tolist(),
        "collisions_last_quarter": bins[:, -q:].sum(axis=1).tolist(),
        "collisions_per_1000_ticks_mean": bins.mean(axis=0).round(2).tolist(),
    }


def table(rows: list[dict], learned_after: int) -> str:
    lines = ["| A+ = A- | paper | median learning time | quartiles | reached | collisions, first -> last quarter |",
             "|---|---|---|---|---|---|"]
    def tick(x, ticks):
        return f"{x:,.0f}" if x is not None else f"> {ticks:,}"

    for r in rows:
        paper = PAPER_TABLE_1.get(f"{r['a_plus']:.2f}")
        first, last = np.mean(r["collisions_first_quarter"]), np.mean(r["collisions_last_quarter"])
        lines.append(f"| {r['a_plus']} | {'' if paper is None else f'{paper:,}'} | {tick(r['median'], r['ticks'])} | "
                     f"{tick(r['quartiles'][0], r['ticks'])} - {tick(r['quartiles'][1], r['ticks'])} | "
                     f"{r['reached']}/{r['seeds']} | {first:.0f} -> {last:.0f} |")
    lines.append(f"\nLearning time: the tick of the last collision event before the first {learned_after:,} "
                 f"collision-free ticks. Median and quartiles over all seeds; a seed that did not get there "
                 f"within {rows[0]['ticks']:,} ticks counts as later than that. Collisions: mean per seed.")
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    for r in rows:
        y = r["collisions_per_1000_ticks_mean"]
        ax.plot((np.arange(len(y)) + 1) * 1000, y, lw=1.5, label=f"A+ = A- = {r['a_plus']} ({r['seeds']} seeds)")
    ax.set(xlabel="tick", ylabel="collision events per 1,000 ticks (mean over seeds)",
           title="Learning speed against the learning rate (paper Table 1)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="spikinglab sweep", description=__doc__.splitlines()[0])
    p.add_argument("--a-plus", type=float, nargs="+", default=[0.01, 0.02, 0.03, 0.04])
    p.add_argument("--seeds", type=int, default=16, help="seeds (arenas 0..N-1) per value (default 16)")
    p.add_argument("--ticks", type=int, default=150_000)
    p.add_argument("--preset", choices=sorted(PRESETS), default="paper")
    p.add_argument("--learned-after", type=int, default=5000)
    p.add_argument("--runs", type=Path, default=Path("runs"))
    p.add_argument("--id", help="folder name (default sweep-<date>)")
    args = p.parse_args(argv)
    from tqdm import tqdm

    folder = args.runs / (args.id or f"sweep-{datetime.datetime.now():%Y%m%d-%H%M%S}")
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    with tqdm(total=args.ticks * len(args.a_plus), unit="tick", unit_scale=True, mininterval=1) as bar:
        for a in args.a_plus:
            bar.set_postfix_str(f"A+ = A- = {a}")
            rows.append(sweep_one(a, args.seeds, args.ticks, args.preset, args.learned_after, bar))
    text = table(rows, args.learned_after)
    (folder / "table.md").write_text(text + "\n")
    (folder / "table.json").write_text(json.dumps(rows, indent=1))
    plot(rows, folder / "learning.png")
    print(text)
    print(f"\nwritten to {folder}/: table.md, table.json, learning.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
