"""Search the insect circuit's own parameters for the fastest learner (CMA-ES, the `cma` library).

Searched, each a value of the circuit file (SPACE): the learning neurons' (PAIN, REWARD) STDP values
A+, A-, tau+, tau-, w_max and threshold; the plastic synapses' start weight and delay; the
sensor-fed inputs' weight; and the fixed weights PAIN -> ROTATE, REWARD -> MOVE, PAIN -| REWARD,
REWARD -| PAIN and H1 -> REWARD (the pacemaker's exploration drive). Every candidate is the insect
circuit (insect.toml) with those values (`circuit_of`), run on every search seed as
`spikinglab.evaluate` runs it, with the distance travelled kept. The world's steps stay the
paper's: a circuit file cannot carry them.

Cost of a candidate (learning time "free 5,000", the project's default; a seed that never learned,
or whose insect crawled slower than MIN_PACE, counts as twice the run): the median over the search
seeds plus their mean (so each seed that never learns costs about twice the run / seeds), plus 100
per collision in the last quarter (mean over seeds). Every generation's best and the final mean then
run on as many validation seeds, and the lowest validation cost wins. Search seeds 1000-1047,
validation seeds 2000-2047; the report's held-out seeds 0-31 are neither (docs/results.md, "A
learner searched for speed", has the command that found FOUND). Needs `pip install -e '.[optimise]'`.
"""

import argparse
import time
import tomllib
from pathlib import Path
from typing import NamedTuple

import cma
import numpy as np

from services.brain.circuit import Circuit, build_circuit, builtin_circuit_path, load_circuit
from services.learning import PAPER, stats, tick_text
from services.loop import closed_loop, population, study_results
from services.options import Parser, at_least, number_within, output_file, positive
from services.world.world import BIN


class Range(NamedTuple):
    low: float
    high: float
    log: bool  # searched on a log scale
    insect: float  # insect.toml's value, inside the range


SPACE = {
    "a_plus": Range(0.005, 0.8, True, 0.02),
    "a_minus": Range(0.005, 0.8, True, 0.02),
    "tau_plus": Range(2.0, 40.0, True, 11.0),
    "tau_minus": Range(3.0, 40.0, True, 18.0),
    "w_max": Range(8.0, 40.0, False, 15.0),
    "threshold": Range(-62.0, -48.0, False, -55.0),  # of PAIN and REWARD
    "initial_weight": Range(1.0, 12.0, False, 5.0),  # the plastic synapses' start weight
    "plastic_delay": Range(1, 8, False, 3),  # ticks, rounded
    "input_weight": Range(12.0, 32.0, False, 20.0),  # of every sensor-fed input neuron
    "pain_rotate": Range(4.0, 25.0, False, 11.0),
    "reward_move": Range(4.0, 25.0, False, 11.0),
    "pain_inhibits_reward": Range(2.0, 40.0, False, 22.0),
    "reward_inhibits_pain": Range(1.0, 30.0, False, 8.0),
    "h1_reward": Range(0.5, 10.0, False, 3.5),
}
INSECT = {name: r.insect for name, r in SPACE.items()}
STDP = ("a_plus", "a_minus", "tau_plus", "tau_minus", "w_max", "threshold")  # the learner type's fields
FIXED = {  # the searched non-plastic synapses: (from, to) in insect.toml -> name
    ("PAIN", "ROTATE"): "pain_rotate",
    ("REWARD", "MOVE"): "reward_move",
    ("PAIN", "REWARD"): "pain_inhibits_reward",
    ("REWARD", "PAIN"): "reward_inhibits_pain",
    ("H1", "REWARD"): "h1_reward",
}
LEARNERS = ("PAIN", "REWARD")  # the neurons the plastic synapses target
MIN_PACE = 0.015  # patches per tick (the insect circuit travels 0.035, at Table 1's best 0.027)
# where CMA-ES starts: the insect with the best per-agent values of an earlier, narrower search (A+,
# A-, tau+, tau-, w_max, start and input weights only); from the insect's own A+ = A- = 0.02 no
# search seed learns within the search's run and the cost is flat
START = INSECT | {
    "a_plus": 0.4164,
    "a_minus": 0.3017,
    "tau_plus": 4.155,
    "tau_minus": 17.5,
    "w_max": 18.62,
    "initial_weight": 4.263,
    "input_weight": 19.75,
}
# the search's result (docs/results.md has its command), which services/brain/circuits/fast_learner.toml
# holds (tests/test_fast_learner.py checks); the report's ablation reverts each change alone
FOUND = {
    "a_plus": 0.3682,
    "a_minus": 0.5188,
    "tau_plus": 3.677,
    "tau_minus": 7.135,
    "w_max": 20.45,
    "threshold": -58.48,
    "initial_weight": 6.681,
    "plastic_delay": 3.0,
    "input_weight": 17.28,
    "pain_rotate": 19.02,
    "reward_move": 16.75,
    "pain_inhibits_reward": 15.95,
    "reward_inhibits_pain": 5.476,
    "h1_reward": 3.344,
}


def circuit_of(values: dict[str, float]) -> Circuit:
    """insect.toml with the values of SPACE (every name in it) set."""
    doc = tomllib.loads(builtin_circuit_path("insect").read_text())
    doc["name"] = "fast_learner"
    doc.setdefault("types", {})["learner"] = {"base": "regular"} | {k: values[k] for k in STDP}
    for name in LEARNERS:
        doc["neurons"][name] = "learner"
    for entry in doc["inputs"].values():
        if "sensor" in entry:
            entry["weight"] = values["input_weight"]
    for s in doc["synapses"]:
        if s.get("plastic"):
            s["weight"], s["delay"] = values["initial_weight"], int(values["plastic_delay"])
        elif (s["from"], s["to"]) in FIXED:
            s["weight"] = values[FIXED[s["from"], s["to"]]]
    return build_circuit(doc, source="insect.toml with searched values")


def to_values(u: np.ndarray) -> dict[str, float]:
    """A point of the unit cube CMA-ES searches -> values, rounded as the circuit file holds them."""
    out = {}
    for x, (name, r) in zip(np.clip(u, 0, 1), SPACE.items()):
        v = r.low * (r.high / r.low) ** x if r.log else r.low + x * (r.high - r.low)
        out[name] = float(round(v)) if name == "plastic_delay" else float(f"{v:.4g}")
    out["initial_weight"] = min(out["initial_weight"], out["w_max"])  # a weight starts within its range
    return out


def to_unit(values: dict[str, float]) -> np.ndarray:
    return np.array(
        [
            np.log(values[n] / r.low) / np.log(r.high / r.low) if r.log else (values[n] - r.low) / (r.high - r.low)
            for n, r in SPACE.items()
        ]
    )


def run(circuit: Circuit, ticks: int, seeds: range, params: dict | None = None) -> dict[str, np.ndarray]:
    """evaluate's result of one setting, [seeds], with "distance" (patches travelled) added."""
    world, brain = population(params or {}, seeds, circuit=circuit)
    closed_loop(world, brain, ticks)
    result = {k: v[0] for k, v in study_results(world, 1, len(seeds)).items()}
    return result | {"distance": world.metrics.distance.copy()}


def learning_times(result: dict[str, np.ndarray], ticks: int) -> np.ndarray:
    """Per seed, the learning time, or twice the run where the insect never learned or crawled
    slower than MIN_PACE (an insect that stands still meets no wall and "learns" at once)."""
    learned = (result["learning_time"] >= 0) & (result["distance"] >= MIN_PACE * ticks)
    return np.where(learned, result["learning_time"], 2 * ticks)


def cost(result: dict[str, np.ndarray], ticks: int) -> float:
    """The search objective (lower is better); see the module's doc."""
    per_seed = learning_times(result, ticks)
    return float(np.median(per_seed) + per_seed.mean() + 100 * result["collisions_last_quarter"].mean())


def summary(result: dict[str, np.ndarray], ticks: int) -> str:
    per_seed = learning_times(result, ticks)
    return f"learned {(per_seed < 2 * ticks).sum()}/{len(per_seed)}, median {np.median(per_seed):,.0f}"


def search(args) -> dict[str, float]:
    """CMA-ES from START; then every generation's best and the final mean run again on the
    validation seeds, and the lowest validation cost wins (a generation's best on the search seeds
    alone is partly the seeds' luck). The winner's values."""
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    opts = {"bounds": [0, 1], "popsize": args.population, "seed": 1, "verbose": -9}
    es = cma.CMAEvolutionStrategy(to_unit(START | args.start), args.sigma, opts)
    candidates = []  # each generation's best
    for generation in range(1, args.generations + 1):
        points = es.ask()
        results = [run(circuit_of(to_values(p)), args.ticks, seeds) for p in points]
        c = [cost(r, args.ticks) for r in results]
        es.tell(points, c)
        k = int(np.argmin(c))
        candidates.append(to_values(points[k]))
        print(f"generation {generation}: best cost {c[k]:,.0f}, {summary(results[k], args.ticks)}", flush=True)
    candidates.append(to_values(es.mean))
    validation = range(args.validation_first_seed, args.validation_first_seed + args.seeds)
    results = [run(circuit_of(v), args.ticks, validation) for v in candidates]
    c = [cost(r, args.ticks) for r in results]
    k = int(np.argmin(c))
    print(
        f"validation: best cost {c[k]:,.0f}, {summary(results[k], args.ticks)} "
        f"(candidate {k + 1} of {len(c)}; the last is the final mean)"
    )
    return candidates[k]


# --- the report: held-out seeds the search never saw (docs/results.md, "A learner searched for speed")


HEADER = (
    "| reverted | median | quartiles | learned | last-quarter collisions | seeds with none | patches travelled |\n"
    + "|---" * 7
    + "|"
)


def table_row(label: str, r: dict[str, np.ndarray], ticks: int) -> str:
    s = stats([int(t) if t >= 0 else None for t in r["learning_time"]], ticks)
    cells = [tick_text(s[k], ticks) for k in ("median", "q1", "q3")]
    last_quarter = r["collisions_last_quarter"]
    return (
        f"| {label} | {cells[0]} | {cells[1]} .. {cells[2]} | {s['reached']}/{s['seeds']} | "
        f"{int(last_quarter.sum())} | {int((last_quarter == 0).sum())}/{len(last_quarter)} | "
        f"{np.median(r['distance']):,.0f} |"
    )


def report_table(args) -> None:
    """Default circuit, the insect at Table 1's best setting and the fast learner, held-out seeds."""
    seeds = range(args.report_first_seed, args.report_first_seed + args.report_seeds)
    print(
        f"held-out seeds {seeds.start}-{seeds.stop - 1}, {args.report_ticks:,} ticks, learning time free 5,000\n"
        f"{HEADER.replace('reverted', 'circuit')}"
    )
    paper_best = min(PAPER, key=lambda a: PAPER[a])
    for label, circuit, params in (
        ("insect (default, A+ = A- = 0.02)", "insect", {}),
        (f"insect at Table 1's best, A+ = A- = {paper_best}", "insect", {"a_plus": paper_best, "a_minus": paper_best}),
        ("fast_learner", "fast_learner", {}),
    ):
        print(
            table_row(label, run(load_circuit(circuit), args.report_ticks, seeds, params), args.report_ticks),
            flush=True,
        )
    print(f"| paper, Table 1 best (A+ = A- = {paper_best}) | {PAPER[paper_best]:,} | - | - | - | - | - |")


def ablation(args) -> None:
    """The fast learner with each change the search made reverted alone to the insect's value."""
    seeds = range(args.report_first_seed, args.report_first_seed + args.report_seeds)
    rows = [("none (the fast learner)", FOUND)] + [
        (f"{name} {value:.4g} -> {INSECT[name]:.4g}", FOUND | {name: INSECT[name]})
        for name, value in FOUND.items()
        if value != INSECT[name]
    ]
    print(HEADER)
    for label, values in rows:
        print(table_row(label, run(circuit_of(values), args.report_ticks, seeds), args.report_ticks), flush=True)


def plot_curves(args, path: str) -> None:
    """Collisions per 1,000 ticks (mean over the held-out seeds): the insect at its default and at
    Table 1's best A+ = A-, and the fast learner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seeds = list(range(args.report_first_seed, args.report_first_seed + args.report_seeds))
    fig, ax = plt.subplots(figsize=(6, 3.2), dpi=90)
    paper_best = min(PAPER, key=lambda a: PAPER[a])
    for label, circuit, params in (
        ("insect (default)", "insect", {}),
        (f"insect, A+ = A- = {paper_best}", "insect", {"a_plus": paper_best, "a_minus": paper_best}),
        ("fast_learner", "fast_learner", {}),
    ):
        world, brain = population(params, seeds, circuit=circuit)
        closed_loop(world, brain, args.report_ticks)
        bins = np.array(world.metrics.bins, np.int64).reshape(-1, world.agents)
        x = (np.arange(len(bins)) + 0.5) * BIN
        ax.plot(x, bins.mean(axis=1), label=label)
    ax.axvline(PAPER[paper_best], color="grey", ls="--", lw=1, label=f"paper's best ({PAPER[paper_best]:,})")
    ax.set(xlabel="tick", ylabel="collisions per 1,000 ticks", title=f"mean over held-out seeds (n = {len(seeds)})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)  # --plot may name a folder still to make
    fig.savefig(path)
    print(f"wrote {path}")


def start_value(text: str) -> tuple[str, float]:
    """NAME=VALUE, the value within NAME's range in SPACE: CMA-ES cannot start outside its bounds."""
    name, _, value = text.partition("=")
    if name not in SPACE:
        raise argparse.ArgumentTypeError(f"{text!r}: not NAME=VALUE with NAME one of {', '.join(SPACE)}")
    return name, number_within(SPACE[name].low, SPACE[name].high, f" for {name}")(value)


# option -> (default, the modes it serves: "" the search, "--report" the report); given in the other mode, refused
MODES = {
    "--generations": (40, ("",)),
    "--population": (16, ("",)),
    "--ticks": (30_000, ("",)),
    "--seeds": (48, ("",)),
    "--first-seed": (1000, ("",)),
    "--validation-first-seed": (2000, ("",)),
    "--sigma": (0.08, ("",)),
    "--start": ([], ("",)),
    "--report-ticks": (60_000, ("--report",)),
    "--report-seeds": (32, ("--report",)),
    "--report-first-seed": (0, ("--report",)),
    "--plot": ("fast-learner.png", ("--report",)),
}


def parser() -> Parser:
    p = Parser(description=(__doc__ or "").splitlines()[0])
    d = {option[2:].replace("-", "_"): default for option, (default, _) in MODES.items()}
    search = p.add_argument_group("a search (without --report)")
    report = p.add_argument_group("the report (with --report)")
    search.add_argument(
        "--generations", type=at_least(1), help=f"generations of the search (default {d['generations']})"
    )
    search.add_argument(
        "--population", type=at_least(2), help=f"candidates per generation, 2 or more (default {d['population']})"
    )
    # the costs read the collisions of the run's last quarter: at least one bin of them
    search.add_argument("--ticks", type=at_least(BIN), help=f"ticks per candidate and seed (default {d['ticks']:,})")
    search.add_argument("--seeds", type=at_least(1), help=f"search seeds, from --first-seed (default {d['seeds']})")
    search.add_argument("--first-seed", type=at_least(0), help=f"the first search seed (default {d['first_seed']})")
    search.add_argument(
        "--validation-first-seed",
        type=at_least(0),
        help=f"as many seeds as --seeds, from here (default {d['validation_first_seed']})",
    )
    search.add_argument(
        "--sigma", type=positive, help=f"CMA-ES's initial step, in the unit cube (default {d['sigma']})"
    )
    search.add_argument("--start", type=start_value, nargs="+", metavar="NAME=VALUE", help="start here, not at START")
    report.add_argument("--report", action="store_true", help="held-out table, ablation and plot instead of a search")
    report.add_argument(
        "--report-ticks", type=at_least(BIN), help=f"ticks per held-out seed (default {d['report_ticks']:,})"
    )
    report.add_argument("--report-seeds", type=at_least(1), help=f"held-out seeds (default {d['report_seeds']})")
    report.add_argument(
        "--report-first-seed", type=at_least(0), help=f"the first held-out seed (default {d['report_first_seed']})"
    )
    report.add_argument(
        "--plot",
        metavar="FILE",
        help=f"the report's plot (default {d['plot']}, in the current folder; docs/fast-learner.png remakes "
        "docs/results.md's figure)",
    )
    return p


def main():
    p = parser()
    args = p.parse_args()
    p.mode_defaults(args, "--report" if args.report else "", MODES)
    if args.report:  # the plot is written after all the report's runs: one it could not write is refused first
        try:
            output_file(args.plot)
        except argparse.ArgumentTypeError as e:
            p.error(f"argument --plot: {e}")
    args.start = dict(args.start)
    if args.report:
        report_table(args)
        ablation(args)
        plot_curves(args, args.plot)
        return
    start = time.perf_counter()
    found = search(args)
    print(f"{time.perf_counter() - start:.0f} s; FOUND = {found}")


if __name__ == "__main__":
    main()
