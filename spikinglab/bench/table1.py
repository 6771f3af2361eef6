"""The paper's Table 1, explained: learning time over a grid of model settings, and an ablation.

grid:      semantics (phased, netlogo) x w_max (9, 15) x steps (paper 5 deg / 1 patch, NetLogo demo
           4 deg / 0.4 patch) x A+ = A- (0.01 .. 0.08), every learning-time definition
           (services/learning.py), median, quartiles, seeds that learned, ratio to A = 0.04.
ablation:  from the setup closest to the NetLogo source, one factor switched at a time.

Every setting is the paper's or the NetLogo source's; nothing is fitted. Each (setting, A) is one
population of --seeds insects (arena and order seed s for insect s) in one process; --workers of
them run at once (default: one per core), or with --device cuda all of them at once on the GPU.
Writes OUT/table1.json, table1.md and table1.png; the last line printed is a JSON summary.
Run: `spikinglab bench table1 [--ablation] [--device cuda]`.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from services.gpu import DEVICES, check_device, simulated
from services.learning import DEFAULT_DEFINITION, DEFINITIONS, PAPER, all_definitions, plot_table1, tick_text
from services.options import Parser, at_least, output_folder, positive

A_VALUES = (0.01, 0.02, 0.03, 0.04, 0.08)
STEPS = {"paper": "paper", "demo": "netlogo"}  # -> world preset

# The setup closest to the NetLogo source (SpikingLab insect demo): its engine and order, its
# w_max 9, its 4 degree / 0.4 patch steps, view distance 4, the 0.5 patch push on a collision.
SOURCE = {
    "semantics": "netlogo",
    "order": "random",
    "without": (),
    "w_max": 9.0,
    "steps": "demo",
    "view_distance": 4.0,
    "push": 0.5,
}
ABLATION = {  # factor -> what it is switched to
    "order: random -> file order": {"order": "file"},
    "delay counting: from the sending tick -> from the next": {"without": ("delay_count",)},
    "refractory: reopens in its turn -> at the next tick": {"without": ("reopen",)},
    "dt = 0 arrivals: again at every arrival -> once": {"without": ("dt0",)},
    "engine: netlogo -> phased (all four above)": {"semantics": "phased"},
    "w_max: 9 -> 15": {"w_max": 15.0},
    "steps: demo 4 deg / 0.4 -> paper 5 deg / 1": {"steps": "paper"},
    "view distance: 4 -> 3": {"view_distance": 3.0},
    "view distance: 4 -> 5": {"view_distance": 5.0},
    "push on collision: 0.5 -> 0 (the later source)": {"push": 0.0},
}


def run_population(setting: dict, a: float, seeds: int, ticks: int, device: str = "cpu") -> dict:
    """One population: `seeds` insects of one setting at A+ = A- = a; collision ticks per insect."""
    from services.brain.circuit import load_circuit
    from services.learning import noxious_ticks
    from services.loop import brain_for
    from services.world.world import World, params_for

    params = params_for(STEPS[setting["steps"]], view_distance=setting["view_distance"], push=setting["push"])
    world = World(params, agents=seeds, seed=0)
    circuit = load_circuit("insect").with_learning_params(a_plus=a, a_minus=a, w_max=setting["w_max"])
    brain = brain_for(
        world, circuit, semantics=setting["semantics"], order=setting["order"], without=setting["without"]
    )
    started = time.perf_counter()
    collisions = noxious_ticks(world, brain, ticks, device=device)  # NetLogo resets its error-free counter in each
    plastic = circuit.plastic_synapses
    m = world.metrics
    return {
        "a": a,
        "device": device,
        "collision_ticks": collisions,
        "seconds": time.perf_counter() - started,
        "weights": {circuit.synapse_label(k): float(np.mean(brain.engine.w[:, k])) for k in plastic},
        # an insect that barely moves is collision-free for free: how far they went, what they ate
        "distance_per_1000": float(m.distance.mean() * 1000 / ticks),
        "food": float(m.food.mean()),
    }


def jobs(ablation: bool, a_values) -> list[tuple[str, dict, float]]:
    """(name, setting, A) for every population to run."""
    out = []
    if ablation:
        for name, change in {"source": {}, **ABLATION}.items():
            for a in a_values:
                out.append((name, {**SOURCE, **change}, a))
        return out
    for semantics in ("phased", "netlogo"):
        for w_max in (9.0, 15.0):
            for steps in ("paper", "demo"):
                setting = {**SOURCE, "semantics": semantics, "w_max": w_max, "steps": steps}
                for a in a_values:
                    out.append((f"{semantics}, w_max {w_max:g}, {steps} steps", setting, a))
    return out


def summarise(name: str, setting: dict, result: dict, seeds: int, ticks: int) -> dict:
    return {
        "name": name,
        "setting": {k: list(v) if isinstance(v, tuple) else v for k, v in setting.items()},
        "a": result["a"],
        "seeds": seeds,
        "ticks": ticks,
        "seconds": round(result["seconds"], 1),
        "device": result["device"],
        "definitions": all_definitions(result["collision_ticks"], ticks),
        "noxious_ticks": [len(c) for c in result["collision_ticks"]],
        "mean_weights": result["weights"],
        "distance_per_1000": round(result["distance_per_1000"], 1),
        "food": round(result["food"], 1),
    }


def ratio(rows: list[dict], row: dict, definition: str) -> str:
    ref = next((r for r in rows if r["name"] == row["name"] and r["a"] == 0.04), None)
    m, m04 = row["definitions"][definition]["median"], ref and ref["definitions"][definition]["median"]
    return f"{m / m04:.2f}" if m is not None and m04 else "-"


def markdown(rows: list[dict], definition: str) -> str:
    lines = [
        f"Learning time ({definition} collision-free ticks unless named), {rows[0]['seeds']} seeds, "
        f"{rows[0]['ticks']:,} ticks: median (quartiles), seeds learned, median / median at A = 0.04.",
        "",
        "| setting | A+ = A- | paper | median (quartiles) | learned | ratio | paper ratio "
        "| patches per 1,000 ticks | food |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        d, t = r["definitions"][definition], r["ticks"]
        paper = PAPER.get(r["a"])
        lines.append(
            f"| {r['name']} | {r['a']} | {'' if paper is None else f'{paper:,}'} | "
            f"{tick_text(d['median'], t)} ({tick_text(d['q1'], t)} - {tick_text(d['q3'], t)}) | "
            f"{d['reached']}/{d['seeds']} | {ratio(rows, r, definition)} | "
            f"{'' if paper is None else f'{paper / PAPER[0.04]:.2f}'} | {r['distance_per_1000']} | {r['food']} |"
        )
    return "\n".join(lines)


def definitions_markdown(rows: list[dict]) -> str:
    names = list(DEFINITIONS)
    lines = ["| setting | A+ = A- | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for r in rows:
        cells = [
            f"{tick_text(r['definitions'][n]['median'], r['ticks'])} ({r['definitions'][n]['reached']})" for n in names
        ]
        lines.append(f"| {r['name']} | {r['a']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n\nMedian learning time (seeds that learned) per definition."


def run_jobs(todo: list[tuple[str, dict, float]], args) -> list[dict]:
    """Every job's summary, in todo's order: --workers processes at once on the CPU, or on the
    device every population at once, a host thread each (they only launch and wait)."""
    from tqdm import tqdm

    if args.device == "cpu":
        pool = ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn"))
    else:
        pool = ThreadPoolExecutor(1 if simulated() else len(todo))  # the simulator runs one kernel at a time
    done: dict[int, dict] = {}  # the summary of each job, by its place in todo
    with (
        pool,
        tqdm(total=len(todo), unit="population", desc="table1" + (" ablation" if args.ablation else "")) as bar,
    ):
        futures = {
            pool.submit(run_population, setting, a, args.seeds, args.ticks, args.device): k
            for k, (_, setting, a) in enumerate(todo)
        }
        for future in as_completed(futures):
            k = futures[future]
            done[k] = summarise(todo[k][0], todo[k][1], future.result(), args.seeds, args.ticks)
            bar.update(1)
    return [done[k] for k in range(len(todo))]


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench table1", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--ablation", action="store_true", help="the ablation table instead of the grid")
    p.add_argument("--seeds", type=at_least(1), default=16, help="insects (arenas 0 .. N-1) per setting (default 16)")
    p.add_argument(
        "--ticks", type=at_least(1000), default=150_000, help="ticks per insect, at least one bin (default 150000)"
    )
    p.add_argument(
        "--a-plus", type=positive, nargs="+", default=None, help=f"A values (default {A_VALUES}; ablation: 0.02 0.04)"
    )
    p.add_argument(
        "--workers",
        type=at_least(1),
        default=len(os.sched_getaffinity(0)),
        help="populations at once on the CPU (default: one per core); with --device cuda, all of them",
    )
    p.add_argument(
        "--out", type=output_folder, default=Path("runs") / "table1", help="where the tables go (default runs/table1)"
    )
    p.add_argument(
        "--device",
        choices=("cpu", *DEVICES),
        default="cpu",
        help="cuda: every population at once on an NVIDIA GPU, a host thread and a stream each (docs/gpu.md)",
    )
    args = p.parse_args(argv)
    if args.device != "cpu":
        try:
            check_device(args.device)
        except RuntimeError as e:
            p.error(str(e))
    a_values = args.a_plus or ((0.02, 0.04) if args.ablation else A_VALUES)
    todo = jobs(args.ablation, a_values)
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    rows = run_jobs(todo, args)
    stem = "ablation" if args.ablation else "table1"
    text = markdown(rows, DEFAULT_DEFINITION) + "\n\n" + definitions_markdown(rows)
    (args.out / f"{stem}.md").write_text(text + "\n")
    (args.out / f"{stem}.json").write_text(json.dumps(rows, indent=1))
    plot_table1(rows, DEFAULT_DEFINITION, args.out / f"{stem}.png")
    print(text)
    print(f"\nwritten to {args.out}/: {stem}.md, {stem}.json, {stem}.png ({time.perf_counter() - started:.0f} s)")
    result = {f"{r['name']} A={r['a']}": r["definitions"][DEFAULT_DEFINITION]["median"] for r in rows}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
