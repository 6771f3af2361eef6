"""`spikinglab run`: train the insect with world and brain as separate processes on the bus.

Starts the world and the brain as two processes on an embedded local bus (no broker: the world
listens on a Unix socket, the brain listens on its own and connects to the world's), shows the
world's progress, and writes
runs/<id>/: metrics.json (the world's), weights.npz (the brain's), summary.json and
collisions.png. Prints where they are. World and brain keep checkpoints in runs/<id>/checkpoint/
while the run lasts: an interrupted run goes on with `spikinglab run --resume runs/<id>`.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from services import snapshots
from services.brain.brain import check_sensors
from services.brain.checkpoint import load_weights
from services.brain.circuit import CircuitError, load_circuit
from services.brain.engine import PARALLEL_FROM
from services.brain.service import add_engine_args, brain_params
from services.launch import STOP_S, Launcher, Process, local_endpoints, options_for
from services.learning import PAPER
from services.options import Parser, agent_list, at_least, positive
from services.params import read_params
from services.recorder.screenshot import last_tick, repair, viewer_command
from services.recorder.service import free_port, viewer_answers, web_viewer_url
from services.world.service import CHECKPOINT, add_world_args, world_from_args
from services.world.world import BIN, SENSORS, MapError
from spikinglab.cli import version

log = logging.getLogger("spikinglab.run")
LIVE_VIEW_WITHIN_S = 60.0  # the recorder's viewer servers are up well within this (a few seconds here)
PAPER_TABLE_1 = {f"{a:.2f}": n for a, n in PAPER.items()}  # keyed as summary.json shows A
STARTED_WITH = "command.json"  # in a run folder: the options the run was started with, for --resume
RESUME_MAY_CHANGE = ("quiet", "no_record", "view")  # how a run is watched, not what it is
KEPT_PARAMS = "params.csv"  # in a run folder: the --params file the run was started with, which world and brain read


def parser() -> argparse.ArgumentParser:
    p = Parser(prog="spikinglab run", description=__doc__.splitlines()[0])
    add_world_args(p)
    p.set_defaults(ticks=100_000)
    p.add_argument(
        "--circuit", default="insect", help="circuit name in services/brain/circuits/ or a .toml path (default insect)"
    )
    p.add_argument(
        "--a-plus",
        type=positive,
        default=None,
        help="A+ = A- of the learning neurons (default: the circuit's, 0.02 for the insect)",
    )
    add_engine_args(p)
    p.add_argument("--load", type=Path, help="start the brain from these weights (.npz checkpoint)")
    p.add_argument("--runs", type=Path, default=Path("runs"), help="where run folders go (default runs/)")
    p.add_argument("--id", help="name of the run folder (default: date, time and seed)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-record", action="store_true", help="no Rerun recording (recording.rrd)")
    p.add_argument(
        "--view",
        action="store_true",
        help="watch the run live: the Rerun viewer when there is a display, else the Rerun web viewer "
        "(its address is printed: open it in a browser)",
    )
    p.add_argument(
        "--detail",
        default="0",
        type=agent_list,
        help="agents recorded in detail, e.g. 0,3: raster, potentials, ... (default 0)",
    )
    p.add_argument(
        "--checkpoint-every",
        type=at_least(1),
        default=10_000,
        metavar="TICKS",
        help="ticks between the checkpoints world and brain keep in runs/<id>/checkpoint/ while the run "
        "lasts (default %(default)s)",
    )
    p.add_argument(
        "--resume",
        type=Path,
        metavar="FOLDER",
        help="go on with the interrupted run in FOLDER (e.g. runs/<id>) from its last checkpoint, with "
        "the options it was started with (--quiet, --no-record and --view may differ)",
    )
    return p


def arguments(p: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """The run's options: those given, or with --resume those the run in that folder was started with."""
    args = p.parse_args(argv)
    if args.resume is None:
        return args
    folder = args.resume
    try:
        started = json.loads((folder / STARTED_WITH).read_text())["argv"]
    except (OSError, ValueError, KeyError, TypeError):
        p.error(f"argument --resume: {folder} is not a run folder of `spikinglab run` (no readable {STARTED_WITH})")
    defaults = vars(p.parse_args([]))
    given = {k for k, v in vars(args).items() if v != defaults[k]} - {"resume", *RESUME_MAY_CHANGE}
    if given:
        p.error(
            f"argument --resume: the run goes on with the options it was started with ({shlex.join(started)}); "
            f"leave out {', '.join('--' + k.replace('_', '-') for k in sorted(given))}"
        )
    watching = [f"--{k.replace('_', '-')}" for k in RESUME_MAY_CHANGE if getattr(args, k)]
    resumed = p.parse_args([*started, *watching])
    resumed.runs, resumed.id, resumed.resume = folder.parent, folder.name, folder
    if resumed.params:  # the copy the run began with: the file given may have changed since
        resumed.params = folder / KEPT_PARAMS
    return resumed


def checkpoint_tick(folder: Path) -> int | None:
    """The tick of the run's last checkpoint in `folder` (None: none kept, the run finished or never got to one)."""
    path = folder / "checkpoint" / CHECKPOINT
    if not path.exists():
        return None
    try:
        return int(snapshots.read(path)[1]["tick"])
    except (ValueError, KeyError, TypeError):
        return None


def main(argv=None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    p = parser()
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    args = arguments(p, argv)
    if args.ticks < BIN:
        p.error(f"argument --ticks: must be at least one bin of collisions ({BIN:,} ticks), got {args.ticks:,}")
    if args.view and args.no_record:
        p.error("argument --view: the live view comes from the recorder, which --no-record leaves out")
    # check everything a user can get wrong before starting any process
    try:
        circuit = load_circuit(args.circuit)
        check_sensors(circuit, SENSORS)
        if args.a_plus is not None:
            circuit = circuit.with_learning_rate(args.a_plus)
        world_from_args(args)  # and the --params file, for the world's agents
        columns = brain_params(args.params, circuit) if args.params else {}
        if args.load:
            load_weights(args.load, circuit)
    except (CircuitError, MapError, ValueError, OSError) as e:
        log.error("spikinglab run: %s", e)
        return 2
    run_id = args.id or f"{datetime.datetime.now():%Y%m%d-%H%M%S}-seed{args.seed}"
    folder = args.runs / run_id
    resume_at = checkpoint_tick(folder)
    if args.resume and resume_at is None:
        log.error(
            "spikinglab run: nothing to resume in %s: no checkpoint (the run finished, or stopped before its "
            "first at tick %s)",
            folder,
            f"{args.checkpoint_every:,}",
        )
        return 2
    if not args.resume and any((folder / name).exists() for name in (STARTED_WITH, "summary.json", "weights.npz")):
        # never over the learning of another run
        log.error(
            "spikinglab run: %s holds a run already%s: choose another --id",
            folder,
            f" (interrupted; go on with it: spikinglab run --resume {folder})" if resume_at is not None else "",
        )
        return 2
    folder.mkdir(parents=True, exist_ok=True)
    if args.resume:
        (folder / "FAILED.txt").unlink(missing_ok=True)  # it said how to go on: this is it
    else:
        (folder / STARTED_WITH).write_text(json.dumps({"argv": argv}))
        if args.params:  # kept with the run, and read from there: what it was is what it stays
            shutil.copyfile(args.params, folder / KEPT_PARAMS)
            args.params = folder / KEPT_PARAMS
    kept = folder / "checkpoint"
    (world_ep, brain_ep), sockets = local_endpoints("world", "brain")

    world = Process(
        "world", "world", options_for("world", args), log=folder / "world.log" if args.quiet else None, raw=True
    )
    world.options.update(
        listen=world_ep,
        out=folder,
        progress=not args.quiet,
        publish_state=not args.no_record,
        checkpoint=kept,
        checkpoint_every=args.checkpoint_every,
    )
    brain = Process("brain", "brain", options_for("brain", args), log=folder / "brain.log")
    brain.options.update(
        listen=brain_ep,
        connect=world_ep,
        once=True,
        save=folder / "weights.npz",
        stats=folder / "brain-stats.json",
        publish_state=not args.no_record,
        checkpoint=kept,
    )  # they wait for the recorder to listen
    # a resumed run's recording goes beside the first: the viewer shows the files as one recording
    recording_file = folder / ("recording.rrd" if resume_at is None else f"recording-from-tick{resume_at}.rrd")
    recorder = Process(
        "recorder",
        "record",
        {"connect": [world_ep, brain_ep], "out": recording_file, "detail": ",".join(map(str, args.detail))},
        log=folder / "recorder.log",
    )
    native = (
        args.view
        and bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
        and viewer_command() is not None
    )
    if args.view:  # the recorder serves the run; a viewer window, or a web viewer, shows it
        recorder.options.update(serve=True, grpc_port=free_port(9876), web=not native)
        if not native:
            recorder.options["web_port"] = free_port(9090)
    if args.agents < PARALLEL_FROM and len(os.sched_getaffinity(0)) >= 2:
        # lock-step latency: world and brain on a core each (a population keeps the brain's threads)
        world.options["cpu"], brain.options["cpu"] = sorted(os.sched_getaffinity(0))[:2]
    log.info(
        "run %s: %d ticks, seed %d, %d agent(s), A+ = A- = %s, world %s%s%s, %s semantics%s",
        run_id,
        args.ticks,
        args.seed,
        args.agents,
        learning_rate(circuit),
        args.preset,
        f", map {args.map}" if args.map else "",
        f", per-agent parameters {', '.join(columns)} from {args.params}" if columns else "",
        args.semantics,
        f"; resumed at tick {resume_at:,}" if resume_at is not None else "",
    )
    started = time.time()
    launcher = Launcher()
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM ends the run as Ctrl-C does
    interrupted = False
    try:
        try:
            for process in ([] if args.no_record else [recorder]) + [world, brain]:
                launcher.start(process)
            if args.view:
                show_live(launcher, recorder.options, native)
            dead = launcher.watch(until="world", optional=("recorder",))  # a run goes on without a recording
        except KeyboardInterrupt:
            interrupted, dead = True, None
            log.warning("\ninterrupted: ending the run at the ticks done (Ctrl-C again to stop at once)")
            launcher.stop("world")  # as Ctrl-C: the world writes what it has and tells the brain to save
        if dead is not None:
            launcher.stop_all(timeout=STOP_S)  # the world writes its ticks done, the brain its learning
            failed(folder, dead)
            return 1
        launcher.finish()  # the brain saves, the recorder writes the rest
    except KeyboardInterrupt:
        log.error("stopped at once: no result written")
        failed(folder, "interrupted twice")
        return 130
    finally:
        launcher.stop_all()
        sockets.cleanup()
    if not (folder / "metrics.json").exists() or not (folder / "weights.npz").exists():
        failed(folder, "interrupted before the first tick" if interrupted else "the world or the brain wrote no result")
        return 130 if interrupted else 1
    if json.loads((folder / "metrics.json").read_text())["ticks"] == 0:  # stopped while the kernels compiled
        failed(folder, "interrupted before the first tick")
        return 130
    recording = (
        None if args.no_record else recording_status(launcher.children["recorder"].popen.returncode, recording_file)
    )
    summary = summarise(folder, args, circuit, run_id, time.time() - started, recording)
    if not summary["headline"]["partial"]:  # the run is whole: its learning is in weights.npz
        shutil.rmtree(kept, ignore_errors=True)
    plot(folder, summary)
    plot_trajectory(folder, summary)
    report(folder, summary)
    return 130 if interrupted else 0


def show_live(launcher: Launcher, options: dict, native: bool) -> None:
    """Once the recorder serves the run: open the Rerun viewer on it (a window of the user's: left
    open), or print the web viewer's address (printed earlier, it would refuse connections)."""
    source = f"rerun+http://127.0.0.1:{options['grpc_port']}/proxy"
    page = None if native else web_viewer_url(options["web_port"], options["grpc_port"])
    deadline = time.monotonic() + LIVE_VIEW_WITHIN_S
    while not (viewer_answers(source) and (page is None or viewer_answers(page))):
        if not all(map(launcher.running, launcher.children)):
            return  # a service ended: watch() says which
        if time.monotonic() > deadline:
            log.warning("no live view: the recorder does not serve the run (its log: recorder.log); the run goes on")
            return
        time.sleep(0.2)
    if native:
        subprocess.Popen(
            [*viewer_command(), source], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
        )
        log.info("live view: the Rerun viewer shows %s", source)
    else:
        log.info("live view (no display here): open %s in a browser; it ends with the run, the recording stays", page)


def recording_status(code: int | None, path: Path) -> dict:
    """Whether the recording (of this process's part of the run) is whole; if its recorder died, the
    file is given its footer back (so that it opens) and the tick it reaches is said."""
    if code == 0:
        return {"complete": True}
    status = {"complete": False, "why": f"the recorder stopped (exit {code})"}
    if path.exists():
        status["repaired"] = repair(path)
        status["last_tick"] = last_tick(path)
    return status


def failed(folder: Path, why: str) -> None:
    """A run folder without a result says so (its logs stay for reading)."""
    metrics = folder / "metrics.json"
    if metrics.exists():
        why += f"; the world stopped at tick {json.loads(metrics.read_text())['ticks']:,} (metrics.json)"
    kept = sorted(path.name for path in folder.glob("weights-*-tick*.npz"))  # the brain's learning when it stopped
    if kept:
        why += f"; the brain's weights when it stopped: {', '.join(kept)}"
    why += resume_hint(folder)
    (folder / "FAILED.txt").write_text(f"this run has no result: {why}; the logs beside this file say more\n")
    log.error("no result in %s (%s); its logs are there", folder, why)


def resume_hint(folder: Path) -> str:
    """How an interrupted run goes on, when it kept a checkpoint."""
    tick = checkpoint_tick(folder)
    return "" if tick is None else f"; go on from its checkpoint at tick {tick:,}: spikinglab run --resume {folder}"


def learning_rate(circuit, which: str = "a_plus") -> float | list[float]:
    """A+ (or A-) of the neurons that learn: one number, or the sorted values if they differ."""
    rates = {getattr(circuit.neuron_types[circuit.synapses[k].post], which) for k in circuit.plastic_synapses}
    return rates.pop() if len(rates) == 1 else sorted(rates)


def summarise(folder: Path, args, circuit, run_id: str, wall_s: float, recording: dict | None = None) -> dict:
    metrics = json.loads((folder / "metrics.json").read_text())
    brain_stats = (
        json.loads((folder / "brain-stats.json").read_text()) if (folder / "brain-stats.json").exists() else {}
    )
    weights = load_weights(folder / "weights.npz", circuit)
    plastic = circuit.plastic_synapses
    columns = read_params(args.params) if args.params else {}
    per_agent = {name: column.tolist() for name, column in columns.items()}
    rates = {which: learning_rate(circuit, which) for which in ("a_plus", "a_minus")}
    for which in set(rates) & set(per_agent):  # set per agent by the --params file
        values = sorted(set(per_agent[which]))
        rates[which] = values[0] if len(values) == 1 else values
    bins = np.array(metrics["collisions_per_1000_ticks"], dtype=float).reshape(args.agents, -1)
    q = max(bins.shape[1] // 4, 1)
    times = metrics["learning_time"]
    learned = sum(t is not None for t in times)
    summary = {
        "headline": {
            "learned": "yes" if learned == len(times) else "no" if not learned else f"{learned} of {len(times)}",
            "learning_time": times if len(times) > 1 else times[0],
            "collisions_first_quarter": round(float(bins[:, :q].sum(axis=1).mean()), 1),
            "collisions_last_quarter": round(float(bins[:, -q:].sum(axis=1).mean()), 1),
            "ticks_done": metrics["ticks"],
            "partial": metrics.get("partial", False),
            "resumed_at": metrics.get("resumed_at"),  # the tick this part of the run went on from (None: from 0)
        },
        "initial_weights": {circuit.synapse_label(k): circuit.synapses[k].weight for k in plastic},
        "final_weights": {circuit.synapse_label(k): weights[:, k].round(4).tolist() for k in plastic},
        "spikinglab": version(),
        "command": " ".join(["spikinglab", "run", *sys.argv[2:]]) if sys.argv[1:2] == ["run"] else " ".join(sys.argv),
        "run": run_id,
        "parameters": {
            "ticks": args.ticks,
            "seed": args.seed,
            "agents": args.agents,
            **rates,
            "circuit": circuit.source,
            "preset": args.preset,
            "map": str(args.map) if args.map else None,
            "shared_arena": args.shared,
            "training": not args.no_training,
            "learned_after": args.learned_after,
            "semantics": args.semantics,
            "order": args.order,
            "per_agent": per_agent,
        },  # the --params file's columns ({}: none)
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


def paper_time(parameters: dict) -> int | None:
    """The paper's Table 1 learning time for the run's A (none when the learning neurons' rates differ)."""
    a_plus = parameters["a_plus"]
    return PAPER.get(a_plus) if isinstance(a_plus, float) else None


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
        title=f"Insect learning to avoid walls and predators (A+ = A- = {p['a_plus']}, seed {p['seed']})",
    )
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(folder / "collisions.png")
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
    fig.suptitle(f"The insect's path (seed {p['seed']}, A+ = A- = {p['a_plus']}, {p['semantics']} semantics)")
    fig.tight_layout()
    fig.savefig(folder / "trajectory.png")
    plt.close(fig)


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
        print(
            f"\nPARTIAL: interrupted after {head['ticks_done']:,} of {summary['parameters']['ticks']:,} ticks"
            + resume_hint(folder)
        )
    print(
        f"\ncollisions: {head['collisions_first_quarter']:.0f} in the first quarter, "
        f"{head['collisions_last_quarter']:.0f} in the last quarter "
        f"({head['ticks_done']:,} ticks, {summary['ticks_per_s']:,.0f} ticks/s)"
    )
    times = summary["learning_time"]
    p = summary["parameters"]
    paper = paper_time(p)
    print(
        f"learned: {head['learned']}"
        f" (criterion: {p['learned_after']:,} ticks off noxious patches); learning time: "
        + ", ".join("not reached" if t is None else f"tick {t:,}" for t in times[:8])
        + (f" (paper, A+ = A- = {p['a_plus']}: {paper:,}; docs/results.md compares)" if paper else "")
    )
    print("weights:", ", ".join(f"{k} {v:.2f}" for k, v in mean.items()))
    # the first part first: recording.rrd, then recording-from-tickN.rrd by N
    recordings = sorted(folder.glob("recording*.rrd"), key=lambda path: (len(path.name), path.name))
    files = ", ".join(
        ["summary.json, collisions.png, trajectory.png, metrics.json, weights.npz", *(path.name for path in recordings)]
    )
    print(f"\nwritten to {folder}/: {files}")
    recording = summary.get("recording", {})
    if not recording.get("complete", True):
        print(
            f"recording: PARTIAL, {recording['why']}; it holds ticks {head['resumed_at'] or 0:,} to "
            f"{recording.get('last_tick', 0):,}"
        )
    if recordings:  # the parts of a resumed run are one recording in the viewer
        print(f"replay it: {viewer_shown()} {' '.join(map(str, recordings))}")


if __name__ == "__main__":
    sys.exit(main())
