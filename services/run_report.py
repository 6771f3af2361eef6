"""What a finished `spikinglab run` writes and prints: summary.json (the headline, the parameters,
the world's metrics and the learnt weights), collisions.png, trajectory.png, and the report on the
terminal."""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

import numpy as np

from services.brain.checkpoint import load_weights
from services.brain.circuit import Circuit
from services.learning import PAPER, quarter_collisions
from services.params import read_params
from services.recorder.viewer import viewer_command
from services.run_folder import recording_parts, resume_hint
from spikinglab.cli import version

PAPER_TABLE_1 = {f"{a:.2f}": n for a, n in PAPER.items()}  # keyed as summary.json shows A


def summarise(
    folder: Path,
    args: argparse.Namespace,
    argv: list[str],
    circuit: Circuit,
    wall_s: float,
    recording: dict | None = None,
) -> dict:
    """summary.json from what world and brain wrote in `folder`; `argv`: the options the run was given."""
    metrics = json.loads((folder / "metrics.json").read_text())
    stats = folder / "brain-stats.json"
    brain_stats = json.loads(stats.read_text()) if stats.exists() else {}
    weights = load_weights(folder / "weights.npz", circuit)
    # per agent, as the final weights: the circuit's, or those loaded (one agent's, or one row per agent)
    started = load_weights(args.load, circuit) if args.load else [synapse.weight for synapse in circuit.synapses]
    started = np.broadcast_to(started, weights.shape)
    initial = {circuit.synapse_label(k): started[:, k].round(4).tolist() for k in circuit.plastic_synapses}
    summary = {
        "headline": headline(metrics, args.agents),
        "initial_weights": initial,
        "final_weights": {circuit.synapse_label(k): weights[:, k].round(4).tolist() for k in circuit.plastic_synapses},
        "spikinglab": version(),
        "command": shlex.join(["spikinglab", "run", *argv]),
        "run": folder.name,
        "parameters": parameters(args, circuit),
        "wall_time_s": round(wall_s, 1),
        "ticks_per_s": metrics["ticks_per_s"],
        "learning_time": metrics["learning_time"],
        "learning_time_definition": metrics["learning_time_definition"],
        "paper_table_1_learning_time": PAPER_TABLE_1,
        "collisions_per_1000_ticks": metrics["collisions_per_1000_ticks"],
        "collisions": metrics["collisions"],
        "food": metrics["food"],
        "all_final_weights": {circuit.synapse_label(k): weights[:, k].tolist() for k in range(weights.shape[1])},
        "world": metrics["world"],
        "rejected_messages": {
            "world": metrics.get("rejected_messages", {}),
            "brain": brain_stats.get("rejected_messages", {}),
        },
    }
    if recording is not None:  # whether recording.rrd holds the whole run
        summary["recording"] = recording
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def headline(metrics: dict, agents: int) -> dict:
    """Whether the insects learnt, and how their collisions fell from the first quarter to the last."""
    bins = np.array(metrics["collisions_per_1000_ticks"], dtype=float).reshape(agents, -1)
    first, last = quarter_collisions(bins)
    whole = bins.shape[1] > 0  # a run of under 1,000 ticks has no bin to compare: None
    times = metrics["learning_time"]
    learned = sum(t is not None for t in times)
    return {
        "learned": "yes" if learned == len(times) else "no" if not learned else f"{learned} of {len(times)}",
        "learning_time": times if len(times) > 1 else times[0],
        "collisions_first_quarter": round(float(first.mean()), 1) if whole else None,
        "collisions_last_quarter": round(float(last.mean()), 1) if whole else None,
        "ticks_done": metrics["ticks"],
        "partial": metrics.get("partial", False),
        "resumed_at": metrics.get("resumed_at"),  # the tick this part of the run went on from (None: from 0)
    }


def parameters(args: argparse.Namespace, circuit: Circuit) -> dict:
    """The run's parameters; `per_agent`: the --params file's columns ({}: none)."""
    per_agent = {name: column.tolist() for name, column in (read_params(args.params) if args.params else {}).items()}
    return {
        "ticks": args.ticks,
        "seed": args.seed,
        "agents": args.agents,
        **learning_rates(circuit, per_agent),
        "circuit": args.given.get("circuit", circuit.source),  # each file as given (the run folder keeps a copy)
        "preset": args.preset,
        "map": args.given.get("map"),
        "load": args.given.get("load"),
        "shared_arena": args.shared,
        "training": not args.no_training,
        "learned_after": args.learned_after,
        "semantics": args.semantics,
        "order": args.order,
        "netlogo_seed": args.netlogo_seed,
        "per_agent": per_agent,
    }


def learning_rates(circuit, per_agent) -> dict:
    """A+ and A- (a_plus, a_minus): the circuit's, or the values a --params file's columns
    (`per_agent`) set, one number where all agents share it."""
    rates = {which: learning_rate(circuit, which) for which in ("a_plus", "a_minus")}
    for which in set(rates) & set(per_agent):
        values = sorted(set(map(float, per_agent[which])))
        rates[which] = values[0] if len(values) == 1 else values
    return rates


def learning_rate(circuit, which: str = "a_plus") -> float | list[float]:
    """A+ (or A-) of the neurons that learn: one number, or the sorted values if they differ."""
    rates = {getattr(circuit.neuron_types[circuit.synapses[k].post], which) for k in circuit.plastic_synapses}
    return rates.pop() if len(rates) == 1 else sorted(rates)


def recording_status(code: int | None, path: Path) -> dict:
    """Whether the recording (of this process's part of the run) is whole; if its recorder died, the
    file is given its footer back (so that it opens) and the tick it reaches is said."""
    if code == 0:
        return {"complete": True}
    from services.recorder.screenshot import last_tick, repair  # rerun (0.5 s to import): only for a file to mend

    status = {"complete": False, "why": f"the recorder stopped (exit {code})"}
    if path.exists():
        status["repaired"] = repair(path)
        status["last_tick"] = last_tick(path)
    return status


def rates_text(parameters: dict) -> str:
    """The learning rates as a title says them: "A+ = A- = 0.02", or each where they differ."""
    a_plus, a_minus = parameters["a_plus"], parameters["a_minus"]
    return f"A+ = A- = {a_plus}" if a_plus == a_minus else f"A+ = {a_plus}, A- = {a_minus}"


def paper_time(parameters: dict) -> int | None:
    """The paper's Table 1 learning time for the run's A (none when the learning neurons' rates differ)."""
    a_plus = parameters["a_plus"]
    return PAPER.get(a_plus) if isinstance(a_plus, float) and a_plus == parameters["a_minus"] else None


def plot(folder: Path, summary: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bins = np.array(summary["collisions_per_1000_ticks"], dtype=float)  # [agents, bins]
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    x = (np.arange(bins.shape[1]) + 1) * 1000
    for row in bins[:20]:
        ax.plot(x, row, color="tab:gray", alpha=0.4, lw=0.8)
    if bins.shape[1]:  # none when a run was stopped within its first 1,000 ticks: an empty plot
        mean = bins.mean(axis=0)
        window = min(5, len(mean))  # a rolling mean over 5,000 ticks shows the trend through the noise
        smooth = np.convolve(mean, np.ones(window) / window, mode="valid")
        who = f"mean of {bins.shape[0]} agents" if len(bins) > 1 else "one insect"
        ax.plot(x[window - 1 :], smooth, color="tab:red", lw=2.5, label=f"{who}, rolling mean over {window},000 ticks")
    p = summary["parameters"]
    learned = [t for t in summary["learning_time"][:20] if t is not None]
    for k, t in enumerate(learned):  # the criterion: the last collision before p["learned_after"] free ticks
        ax.axvline(
            t,
            color="tab:green",
            ls="--",
            lw=1,
            label=None if k else f"learned: last collision before {p['learned_after']:,} collision-free ticks",
        )
    paper = paper_time(p)
    if paper:
        ax.axvline(paper, color="black", ls=":", lw=1.5, label=f"the paper's learning time at this A: {paper:,}")
    ax.set(
        xlabel="tick",
        ylabel="collision events per 1,000 ticks",
        title=f"Insect learning to avoid walls and predators ({rates_text(p)}, seed {p['seed']})"
        + partial_mark(summary),
    )
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(folder / "collisions.png", metadata={"Title": ax.get_title()})
    plt.close(fig)


def plot_trajectory(folder: Path, summary: dict) -> None:
    """trajectory.png: agent 0's path early and late in the run on its map (the paper's fig. 8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    data = np.load(folder / "trajectory.npz")
    x0, y0 = int(data["x_min"]), int(data["y_min"])
    colours = ListedColormap(["white", "dimgray", "tab:red", "tab:green"])  # empty, wall, predator, food
    fig, axes = plt.subplots(1, 2, figsize=(10, 7), dpi=100)
    n = len(data["early"])
    for ax, path, grid, title in (
        (axes[0], data["early"], data["grid_early"], f"ticks 0 - {n:,}: early in training"),
        (
            axes[1],
            data["late"],
            data["grid_late"],
            f"ticks {int(data['late_from']):,} - {int(data['late_from']) + n:,}: late",
        ),
    ):
        ax.imshow(
            grid.T,
            origin="lower",
            cmap=colours,
            vmin=0,
            vmax=3,
            extent=(x0 - 0.5, x0 + grid.shape[0] - 0.5, y0 - 0.5, y0 + grid.shape[1] - 0.5),
        )
        jumps = np.flatnonzero(np.hypot(*np.diff(path, axis=0).T) > 2) + 1  # put back at the start: no line
        for piece in np.split(path, jumps):
            ax.plot(piece[:, 0], piece[:, 1], color="tab:blue", lw=1)
        ax.set(title=title, xticks=[], yticks=[])
    p = summary["parameters"]
    fig.suptitle(
        f"The insect's path (seed {p['seed']}, {rates_text(p)}, {p['semantics']} semantics)" + partial_mark(summary)
    )
    fig.tight_layout()
    fig.savefig(folder / "trajectory.png", metadata={"Title": fig.get_suptitle()})
    plt.close(fig)


def partial_mark(summary: dict) -> str:
    """A plot title's second line where the run was interrupted, as the terminal says it."""
    head = summary["headline"]
    if not head["partial"]:
        return ""
    return f"\nPARTIAL: interrupted after {head['ticks_done']:,} of {summary['parameters']['ticks']:,} ticks"


def viewer_shown() -> str:
    """The viewer command to print: the `rerun` this install has (a venv's beside its Python, else
    on PATH), relative to here when under it; `rerun` (from rerun-sdk) if none is found."""
    found = viewer_command()
    if found is None:
        return "rerun"
    try:
        return str(Path(found[0]).relative_to(Path.cwd()))
    except ValueError:  # not under the current folder (or not absolute): as found
        return found[0]


def report(folder: Path, summary: dict) -> None:
    head = summary["headline"]
    w = summary["final_weights"]
    mean = {k: float(np.mean(v)) for k, v in w.items()}
    if head["partial"]:
        print(partial_mark(summary) + resume_hint(folder))
    times = summary["learning_time"]
    p = summary["parameters"]
    paper = paper_time(p)
    of_all = f" (mean of {p['agents']:,} insects)" if p["agents"] > 1 else ""
    resumed = head["resumed_at"]
    pace = f"{summary['ticks_per_s']:,.0f} ticks/s" + (f" from tick {resumed:,}, where it resumed" if resumed else "")
    first, last = head["collisions_first_quarter"], head["collisions_last_quarter"]
    quarters = (
        f"{first:.0f} in the first quarter, {last:.0f} in the last quarter"
        if last is not None
        else "none compared (no whole 1,000 ticks)"
    )
    print(f"\ncollisions{of_all}: {quarters} ({head['ticks_done']:,} ticks, {pace})")
    print(
        f"learned: {head['learned']}"
        f" (criterion: {p['learned_after']:,} ticks off noxious patches); learning time: "
        + ", ".join("not reached" if t is None else f"tick {t:,}" for t in times[:8])
        + (f" ... (the first 8 of {len(times):,}: summary.json has each)" if len(times) > 8 else "")
        + (f" (paper, {rates_text(p)}: {paper:,}; docs/results.md compares)" if paper else "")
    )
    print(f"weights{of_all}:", ", ".join(f"{k} {v:.2f}" for k, v in mean.items()))
    recordings = recording_parts(folder)
    files = ", ".join(
        ["summary.json, collisions.png, trajectory.png, metrics.json, weights.npz", *(path.name for path in recordings)]
    )
    print(f"\nwritten to {folder}/: {files}")
    recording = summary.get("recording", {})
    if not recording.get("complete", True):
        held = (
            f"; it holds ticks {head['resumed_at'] or 0:,} to {recording['last_tick']:,}"
            if "last_tick" in recording
            else ""
        )
        print(f"recording: PARTIAL, {recording['why']}{held}")
    if recordings:  # the parts of a resumed run are one recording in the viewer
        print(f"replay it: {viewer_shown()} {' '.join(map(str, recordings))}")
