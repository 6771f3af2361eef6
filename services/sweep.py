"""`spikinglab sweep`: the paper's Table 1 — learning time for symmetric A+ = A- over several seeds.

All values and seeds run as one population in one process (one arena each; each A+ value is a
per-agent parameter), so a sweep takes seconds; with --cluster, in blocks on a Dask cluster, with
the same table. Writes runs/<id>/table.md, table.json and learning.png, and prints the table beside
the paper's numbers.
"""

from __future__ import annotations

import argparse
import datetime
import json
import signal
import sys
from functools import partial
from pathlib import Path

import numpy as np

from services.brain.engine import DEFAULT_SEMANTICS
from services.brain.engine_options import add_engine_args
from services.cluster import ClusterError, address_option, check_cluster
from services.gpu import DEVICES, check_device
from services.interrupts import ctrl_c_held
from services.learning import PAPER, all_definitions, noxious_ticks, plot_table1, quarter_collisions, stats
from services.loop import population
from services.options import Parser, add_netlogo_seed, at_least, folder_name, output_folder, positive
from services.world.netlogo_setup import spikinglab_setup
from services.world.options import add_learned_after, add_preset
from services.world.world import BIN, params_for


def sweep(
    a_values: list[float],
    seeds: int,
    ticks: int,
    preset: str,
    learned_after: int,
    progress=None,
    semantics: str = DEFAULT_SEMANTICS,
    order: str = "random",
    cluster: str | None = None,
    netlogo_seed: int | None = None,
    device: str = "cpu",
) -> list[dict]:
    """Every A+ = A- value on seeds 0..N-1 (agent = value-major, then seed); a row per value. In
    this process as one population (`progress.update(1)` per tick), or on the Dask scheduler at
    `cluster` in blocks (`progress.update(insects)` per block), with the same rows. `netlogo_seed`:
    every insect in the SpikingLab source's arena of `random-seed N`; the seeds vary its order.
    `device`: "cuda" runs the population on an NVIDIA GPU (services/gpu.py), with the same rows."""
    check_seeds_differ(netlogo_seed, semantics, order)
    if device != "cpu":
        check_device(device, cluster)
    options: dict = dict(
        preset=preset, learned_after=learned_after, semantics=semantics, order=order, netlogo_seed=netlogo_seed
    )
    if cluster is None:
        on_tick = (lambda t: progress.update(1)) if progress else None
        found = insects(a_values, list(range(seeds)), ticks, on_tick=on_tick, device=device, **options)
    else:
        found = on_cluster(cluster, a_values, seeds, ticks, progress, options)
    out = rows(a_values, seeds, ticks, preset, semantics, found)
    for r in out:
        r["netlogo_seed"] = netlogo_seed  # None: each seed its own arena
        if netlogo_seed is not None:
            r["name"] += f", the source's arena of random-seed {netlogo_seed}"
    return out


def insects(
    a_values: list[float],
    seeds: list[int],
    ticks: int,
    preset: str,
    learned_after: int,
    semantics: str,
    order: str,
    netlogo_seed: int | None = None,
    on_tick=None,
    device: str = "cpu",
) -> dict:
    """Every value on every seed as one population: per insect (value-major, then seed) its ticks
    on a noxious patch ("noxious"), its collisions per bin ("bins") and the world's learning time."""
    world, brain = population(
        {"a_plus": a_values, "a_minus": a_values},
        seeds,
        preset=preset,
        learned_after=learned_after,
        semantics=semantics,
        order=order,
        netlogo_seed=netlogo_seed,
    )
    noxious = noxious_ticks(world, brain, ticks, on_tick, device)
    return {
        "device": device,
        "noxious": [np.asarray(c, np.int64) for c in noxious],
        "bins": np.array(world.metrics.bins).T,  # [agents, ticks / 1000]
        "learned_at": world.metrics.learned_at.copy(),
    }


def check_seeds_differ(netlogo_seed: int | None, semantics: str, order: str) -> None:
    """ValueError where the source's arena leaves the seeds nothing to vary: its arena and heading
    are every insect's, so only the netlogo semantics' random order tells one seed from another."""
    if order == "netlogo-stream":
        raise ValueError(
            "--order netlogo-stream draws every insect's order from the one stream of the source's "
            "setup, so the seeds would be one run copied: run it alone with spikinglab run --preset "
            "netlogo --netlogo-seed N --order netlogo-stream"
        )
    if netlogo_seed is not None and (semantics, order) != ("netlogo", "random"):
        raise ValueError(
            f"--netlogo-seed gives every seed the same arena and heading, so the seeds differ only by "
            f"the netlogo semantics' random order; with --semantics {semantics} --order {order} they "
            f"would be one run copied: drop --netlogo-seed or use --semantics netlogo --order random"
        )


def sweep_block(a_values: list[float], ticks: int, options: dict, chosen: range, at: range) -> dict:
    """One block of a sweep on a cluster worker: the chosen values on seeds `at`."""
    return insects([a_values[k] for k in chosen], list(at), ticks, **options)


def on_cluster(address: str, a_values: list[float], seeds: int, ticks: int, progress, options: dict) -> dict:
    """`insects` for every value on seeds 0..N-1, in blocks on the cluster at `address`."""
    from services.cluster import in_blocks  # the cluster's packages only when one is named

    found: dict = {"noxious": [None] * (len(a_values) * seeds)}
    task = partial(sweep_block, a_values, ticks, options)
    for chosen, at, part in in_blocks(address, task, len(a_values), seeds):
        agents = [k * seeds + j for k in chosen for j in at]
        for agent, c in zip(agents, part["noxious"]):  # type: ignore[index]
            found["noxious"][agent] = c
        for name in ("bins", "learned_at"):
            values = part[name]  # type: ignore[index]
            found.setdefault(name, np.empty((len(found["noxious"]), *values.shape[1:]), values.dtype))[agents] = values
        if progress:
            progress.update(len(agents))
    return found


def rows(a_values: list[float], seeds: int, ticks: int, preset: str, semantics: str, found: dict) -> list[dict]:
    """A row per value from its insects' records (`insects`)."""
    out = []
    for k, a_plus in enumerate(a_values):
        mine = slice(k * seeds, (k + 1) * seeds)
        bins = found["bins"][mine]
        first_quarter, last_quarter = quarter_collisions(bins)
        definitions = all_definitions(found["noxious"][mine], ticks)
        times = [int(t) if t >= 0 else None for t in found["learned_at"][mine]]  # the world's own counter
        main = {"times": times, **stats(times, ticks)}
        out.append(
            {
                "name": f"{semantics} semantics, {preset} steps",
                "a": a_plus,
                "a_plus": a_plus,
                "seeds": seeds,
                "ticks": ticks,
                "device": found.get("device", "cpu"),  # where the insects ran
                "learning_time": main["times"],
                "reached": main["reached"],
                "median": main["median"],
                "quartiles": [main["q1"], main["q3"]],
                "definitions": {**definitions, "project": main},
                "collisions_first_quarter": first_quarter.tolist(),
                "collisions_last_quarter": last_quarter.tolist(),
                "collisions_per_1000_ticks_mean": bins.mean(axis=0).round(2).tolist(),
            }
        )
    return out


def table(rows: list[dict], learned_after: int) -> str:
    lines = [
        "| A+ = A- | paper | median learning time | quartiles | reached | collisions, first -> last quarter |",
        "|---|---|---|---|---|---|",
    ]

    def tick(x, ticks):
        return f"{x:,.0f}" if x is not None else f"> {ticks:,}"

    for r in rows:
        paper = PAPER.get(r["a_plus"])
        first, last = np.mean(r["collisions_first_quarter"]), np.mean(r["collisions_last_quarter"])
        lines.append(
            f"| {r['a_plus']} | {'' if paper is None else f'{paper:,}'} | {tick(r['median'], r['ticks'])} | "
            f"{tick(r['quartiles'][0], r['ticks'])} - {tick(r['quartiles'][1], r['ticks'])} | "
            f"{r['reached']}/{r['seeds']} | {first:.0f} -> {last:.0f} |"
        )
    lines.append(
        f"\nLearning time: the last tick on a noxious patch before the first {learned_after:,} ticks off "
        f"them. Median and quartiles over all seeds; a seed that did not get there within "
        f"{rows[0]['ticks']:,} ticks counts as later than that. Collisions: mean per seed."
    )
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    for r in rows:
        y = r["collisions_per_1000_ticks_mean"]
        (line,) = ax.plot(
            (np.arange(len(y)) + 1) * 1000, y, lw=1.5, label=f"A+ = A- = {r['a_plus']} ({r['seeds']} seeds)"
        )
        if r["median"] is not None:  # the median learning time (dashed) and the paper's (dotted), in its colour
            ax.axvline(r["median"], color=line.get_color(), ls="--", lw=1)
        if PAPER.get(r["a_plus"]):
            ax.axvline(PAPER[r["a_plus"]], color=line.get_color(), ls=":", lw=1.5)
    ax.plot([], [], color="gray", ls="--", label="median learning time")
    ax.plot([], [], color="gray", ls=":", label="the paper's learning time (Table 1)")
    ax.set(
        xlabel="tick",
        ylabel="collision events per 1,000 ticks (mean over seeds)",
        title="Learning speed against the learning rate (paper Table 1)",
    )
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def run_with_progress(args) -> list[dict]:
    """The sweep of the command's arguments, its progress shown: ticks in one process, insects on a cluster."""
    from tqdm import tqdm

    insects = len(args.a_plus) * args.seeds
    total, unit = (args.ticks, "tick") if args.cluster is None else (insects, "insect")
    with tqdm(total=total, unit=unit, unit_scale=unit == "tick", mininterval=1) as bar:
        bar.set_postfix_str(f"{insects} insects: A+ = A- in {args.a_plus} x {args.seeds} seeds")
        return sweep(
            args.a_plus,
            args.seeds,
            args.ticks,
            args.preset,
            args.learned_after,
            bar,
            args.semantics,
            args.order,
            args.cluster,
            args.netlogo_seed,
            args.device,
        )


def each_value_once(args: argparse.Namespace) -> None:
    """--a-plus: a value given twice would be a row twice in the table."""
    twice = sorted({a for a in args.a_plus if args.a_plus.count(a) > 1})
    if twice:
        raise ValueError(f"argument --a-plus: {twice[0]:g} given twice")


def parser() -> Parser:
    p = Parser(prog="spikinglab sweep", description=(__doc__ or "").partition("\n")[0], together=[each_value_once])
    p.add_argument(
        "--a-plus",
        type=positive,
        nargs="+",
        default=[0.01, 0.02, 0.03, 0.04],
        metavar="A",
        help="the values of A+ = A- (default: the paper's Table 1, 0.01 0.02 0.03 0.04)",
    )
    p.add_argument("--seeds", type=at_least(1), default=16, help="seeds (arenas 0..N-1) per value (default 16)")
    p.add_argument(
        "--ticks",
        type=at_least(BIN),
        default=150_000,
        help=f"ticks per seed, at least one bin of {BIN:,} (default 150,000)",
    )
    add_preset(p)
    add_learned_after(p)
    add_netlogo_seed(
        p,
        "every insect in the arena and first heading of the SpikingLab source's setup after "
        "`random-seed N` (its own: 7850); the seeds then vary the neurons' order (docs/netlogo-random.md)",
    )
    add_engine_args(p)
    p.add_argument(
        "--runs",
        type=output_folder,
        default=Path("runs"),
        help="where the sweep's folder goes (default runs/)",
    )
    p.add_argument("--id", type=folder_name, help="the sweep's folder name (default sweep-<date>-<time>)")
    p.add_argument(
        "--cluster",
        type=address_option,
        metavar="ADDRESS",
        help="run on the Dask scheduler at tcp://HOST:PORT, in blocks of insects (docs/cluster.md)",
    )
    p.add_argument(
        "--device",
        choices=("cpu", *DEVICES),
        default="cpu",
        help="cuda: the population on an NVIDIA GPU (docs/gpu.md; needs the gpu extra), the same table",
    )
    return p


def main(argv=None) -> int:
    try:
        p = parser()
        args = p.parse_args(argv)
        try:
            check_seeds_differ(args.netlogo_seed, args.semantics, args.order)
            if args.id and any((args.runs / args.id / name).exists() for name in RESULTS):
                raise ValueError(f"argument --id: {args.runs / args.id} holds a sweep already: choose another --id")
            if args.device != "cpu":
                check_device(args.device, args.cluster)
            if args.netlogo_seed is not None:
                spikinglab_setup(args.netlogo_seed, params_for(args.preset))  # its range and arena, before any run
        except (ValueError, RuntimeError) as e:
            p.error(str(e))
        if args.cluster is not None:
            check_cluster(args.cluster)  # before the progress bar: its one line alone
    except KeyboardInterrupt:
        print("spikinglab sweep: interrupted, no table written", file=sys.stderr)
        return 130
    except ClusterError as e:
        print(f"spikinglab sweep: {e}", file=sys.stderr)
        return 1
    return run_into_folder(args)


RESULTS = ("table.md", "table.json", "learning.png", "table1.png")  # a sweep's files in its folder


def run_into_folder(args) -> int:
    """The sweep, its table and figures written to its folder all together or not at all: each under
    a temporary name first (a figure keeps its suffix, which names its format), then renamed."""
    folder = args.runs / (args.id or f"sweep-{datetime.datetime.now():%Y%m%d-%H%M%S}")
    created = not folder.exists()
    unfinished = {name: folder / f".partial-{name}" for name in RESULTS}
    written = False
    on_ctrl_c = signal.getsignal(signal.SIGINT)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        rows = run_with_progress(args)
        text = table(rows, args.learned_after)
        unfinished["table.md"].write_text(text + "\n")
        unfinished["table.json"].write_text(json.dumps(rows, indent=1))
        plot(rows, unfinished["learning.png"])
        plot_table1(rows, "project", unfinished["table1.png"])
        with ctrl_c_held():  # one rename cannot be cut in half, four can
            for name, path in unfinished.items():
                path.replace(folder / name)
            written = True
        print(text)
        print(
            f"\nwritten to {folder}/: table.md, table.json, learning.png (collisions over time), "
            f"table1.png (against the paper)"
        )
        return 0
    except ClusterError as e:
        print(f"spikinglab sweep: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut the ending short
        said = f"the table is written to {folder}/" if written else "no table written"
        print(f"spikinglab sweep: interrupted, {said}", file=sys.stderr)
        return 130
    finally:
        if not written:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            for path in unfinished.values():
                path.unlink(missing_ok=True)
            if created and folder.exists() and not any(folder.iterdir()):  # a failed rename's files stay
                folder.rmdir()
        signal.signal(signal.SIGINT, on_ctrl_c)


if __name__ == "__main__":
    sys.exit(main())
