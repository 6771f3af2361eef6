"""`spikinglab run`: train the insect with world and brain as separate processes on the bus.

Starts the world, the brain and the recorder as processes on an embedded local bus (no broker, no
network: the world listens on a Unix socket, the brain and the recorder each on their own, in a
private folder; the brain connects to the world's, the recorder to both), shows the world's
progress, and writes runs/<id>/: metrics.json (the world's), weights.npz (the brain's),
summary.json, collisions.png, trajectory.png and recording.rrd. Prints where they are. World and
brain keep checkpoints in runs/<id>/checkpoint/ while the run lasts: an interrupted run goes on
with `spikinglab run --resume runs/<id>`.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shlex
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from services.brain.brain import check_sensors
from services.brain.build import check_options
from services.brain.checkpoint import load_weights
from services.brain.circuit import Circuit, CircuitError, load_circuit
from services.brain.engine import PARALLEL_FROM
from services.brain.engine_options import add_engine_args, brain_params, learning_options_fit
from services.launch import STOP_S, Launcher, Process, local_endpoints, options_for
from services.options import (
    Parser,
    UsageError,
    agent_list,
    at_least,
    config_from,
    folder_name,
    ip_address,
    output_folder,
    positive,
)
from services.run_folder import (
    STARTED_WITH,
    RunFolderError,
    failed,
    kept_files,
    new_folder,
    recording_part,
    recording_parts,
    started_with,
    take,
)
from services.run_report import (
    learning_rates,
    plot,
    plot_trajectory,
    rates_text,
    recording_status,
    report,
    summarise,
)
from services.world.options import WorldOptions, add_world_args, world_from
from services.world.world import BIN, SENSORS, MapError

log = logging.getLogger("spikinglab.run")
RESUME_MAY_CHANGE = ("quiet", "no_record", "view", "view_host")  # how a run is watched, not what it is
LOCAL = "127.0.0.1"  # the live view's servers listen here unless --view-host says otherwise


def parser() -> argparse.ArgumentParser:
    p = Parser(prog="spikinglab run", description=(__doc__ or "").partition("\n")[0], together=[learning_options_fit])
    add_world_args(p, ticks=100_000, least_ticks=BIN, why=f", at least {BIN:,}: one bin of collisions")
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
    p.add_argument("--load", type=Path, help="start the brain from these weights (a run's weights.npz)")
    p.add_argument("--runs", type=output_folder, default=Path("runs"), help="where run folders go (default runs/)")
    p.add_argument("--id", type=folder_name, help="name of the run folder (default: date, time and seed)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-record", action="store_true", help="no Rerun recording (recording.rrd)")
    p.add_argument(
        "--view",
        action="store_true",
        help="watch the run live: the Rerun viewer when there is a display, else the Rerun web viewer "
        "(its address is printed: open it in a browser)",
    )
    p.add_argument(
        "--view-host",
        type=ip_address,
        default=LOCAL,
        metavar="ADDRESS",
        help="the address the live view's servers listen on (default %(default)s: this machine only; "
        "0.0.0.0: every interface, for a browser on another machine, which replaces 127.0.0.1 in the "
        "address printed with this machine's)",
    )
    p.add_argument(
        "--detail",
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
        help="go on with the interrupted run in FOLDER (e.g. runs/<id>) from its last checkpoint, with the "
        "options it was started with; how it is watched (--quiet, --no-record, --view, --view-host) is as given now",
    )
    return p


def arguments(p: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """The run's options: those given, or with --resume those the run in that folder was started with."""
    args = p.parse_args(argv)
    if args.resume is not None:
        args = resumed(p, args)
    if args.view and args.no_record:
        p.error("argument --view: the live view comes from the recorder, which --no-record leaves out")
    if args.detail is not None and args.no_record:
        p.error("argument --detail: says what the recording holds, which --no-record leaves out")
    args.detail = args.detail or (0,)
    if max(args.detail) >= args.agents:
        p.error(f"argument --detail: agent {max(args.detail)} of {args.agents} (agents are 0 .. {args.agents - 1})")
    if args.view_host != LOCAL and not args.view:
        p.error("argument --view-host: it says where the live view listens, which only --view starts")
    try:  # the brain would refuse them only after the world has started
        check_options(args.agents, args.semantics, args.order, (), args.netlogo_seed)
    except ValueError as e:
        p.error(str(e))
    return args


def resumed(p: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.Namespace:
    """The options the run in the --resume folder was started with, and how it is watched now."""
    folder = args.resume
    try:
        started = started_with(folder)
    except RunFolderError as e:
        p.error(f"argument --resume: {e}")
    defaults = vars(p.parse_args([]))
    given = {k for k, v in vars(args).items() if v != defaults[k]} - {"resume", *RESUME_MAY_CHANGE}
    if given:
        p.error(
            f"argument --resume: the run goes on with the options it was started with ({shlex.join(started)}); "
            f"leave out {', '.join('--' + k.replace('_', '-') for k in sorted(given))}"
        )
    p.exit_on_error = False  # an error names the file the options came from, not the command line
    try:
        options = p.parse_args(started)
    except (argparse.ArgumentError, UsageError) as e:
        p.exit_on_error = True
        p.error(f"argument --resume: {folder / STARTED_WITH} holds options this run refuses: {e}")
    p.exit_on_error = True
    for k in RESUME_MAY_CHANGE:  # as given now: a run started --quiet or --no-record goes on shown or recorded
        setattr(options, k, getattr(args, k))
    options.runs, options.id, options.resume = folder.parent, folder.name, folder
    kept_files(folder, options)  # the copies the run began with: the files given may have changed since
    return options


def main(argv=None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    args = arguments(parser(), argv)
    try:  # everything a user can get wrong, before any process starts
        circuit, columns = checked_inputs(args)
        folder = args.runs / args.id if args.id else new_folder(args.runs, args.seed)
        resume_at = take(folder, args, argv, circuit)
    except (CircuitError, MapError, RunFolderError, ValueError, OSError) as e:
        log.error("spikinglab run: %s", e)
        return 2
    run = RunProcesses.of(args, folder, resume_at)
    view = None
    if args.view:
        from services.live_view import live_view  # rerun's viewer: only for a run watched live

        view = live_view(args.view_host)
        run.recorder.options.update(view.recorder_options())
    announce(args, circuit, columns, folder.name, resume_at)
    started = time.time()
    code, interrupted, recorder_code = launch(run, folder, view)
    if code is not None:
        return code
    if not (folder / "metrics.json").exists() or not (folder / "weights.npz").exists():
        failed(folder, "interrupted before the first tick" if interrupted else "the world or the brain wrote no result")
        return 130 if interrupted else 1
    recording = None if run.recording is None else recording_status(recorder_code, run.recording)
    if run.recording is None and resume_at is not None and recording_parts(folder):
        recording = {"complete": False, "why": f"this part, from tick {resume_at:,}, was not recorded (--no-record)"}
    summary = summarise(folder, args, argv, circuit, time.time() - started, recording)
    if not summary["headline"]["partial"]:  # the run is whole: its learning is in weights.npz
        shutil.rmtree(folder / "checkpoint", ignore_errors=True)
    plot(folder, summary)
    plot_trajectory(folder, summary)
    report(folder, summary)
    return 130 if interrupted else 0


def checked_inputs(args: argparse.Namespace) -> tuple[Circuit, dict]:
    """The circuit (with --a-plus), checked against the world's sensors; the world's options and
    the --params file's columns for the brain, checked; the --load weights, checked to fit."""
    circuit = load_circuit(args.circuit)
    check_sensors(circuit, SENSORS)
    if args.a_plus is not None:
        circuit = circuit.with_learning_rate(args.a_plus)
    world_from(config_from(args, WorldOptions, whole=False))  # and the --params file, for the world's agents
    columns = brain_params(args.params, circuit, args.a_plus) if args.params else {}
    loaded = len(load_weights(args.load, circuit, w_max=columns.get("w_max"))) if args.load else 1
    if loaded not in (1, args.agents):
        raise ValueError(f"{args.load}: weights of {loaded} agents, the run has {args.agents} (or give one agent's)")
    return circuit, columns


@dataclass
class RunProcesses:
    """The run's service processes, on Unix sockets in a private folder (`sockets`)."""

    world: Process
    brain: Process
    recorder: Process
    recording: Path | None  # the recorder's file (None: --no-record, no recorder)
    sockets: tempfile.TemporaryDirectory

    @classmethod
    def of(cls, args: argparse.Namespace, folder: Path, resume_at: int | None) -> RunProcesses:
        kept = folder / "checkpoint"
        (world_ep, brain_ep, recorder_ep), sockets = local_endpoints("world", "brain", "recorder")
        recording = recording_part(folder, resume_at)
        on_the_bus = {"publish_state": not args.no_record, "checkpoint": kept}  # they wait for the recorder
        world_log = folder / "world.log" if args.quiet else None  # else its progress bar, as it is
        world = Process("world", "world", options_for("world", args), log=world_log, raw=True)
        world.options.update(
            listen=world_ep, out=folder, progress=not args.quiet, checkpoint_every=args.checkpoint_every, **on_the_bus
        )
        if world_log is None:  # its lines in the run's folder too, as the others'
            world.options["log_file"] = folder / "world.log"
        brain = Process("brain", "brain", options_for("brain", args), log=folder / "brain.log")
        brain.options.update(
            listen=brain_ep,
            connect=world_ep,
            once=True,
            save=folder / "weights.npz",
            stats=folder / "brain-stats.json",
            **on_the_bus,
        )
        # its own Unix socket: a Zenoh peer given none would listen on TCP, on every interface
        recorder_options = {"listen": recorder_ep, "connect": [world_ep, brain_ep], "out": recording}
        recorder_options["detail"] = ",".join(map(str, args.detail))
        recorder = Process("recorder", "record", recorder_options, log=folder / "recorder.log")
        if args.agents < PARALLEL_FROM and len(os.sched_getaffinity(0)) >= 2:
            # lock-step latency: world and brain on a core each (a population keeps the brain's threads)
            world.options["cpu"], brain.options["cpu"] = sorted(os.sched_getaffinity(0))[:2]
        return cls(world, brain, recorder, None if args.no_record else recording, sockets)


def announce(args: argparse.Namespace, circuit: Circuit, columns: dict, run_id: str, resume_at: int | None) -> None:
    log.info(
        "run %s: %d ticks, seed %d, %d agent(s), %s, world %s%s%s, %s semantics%s",
        run_id,
        args.ticks,
        args.seed,
        args.agents,
        rates_text(learning_rates(circuit, columns)),
        args.preset,
        f", map {args.given.get('map')}" if args.map else "",  # the files as given (the run reads its copies)
        f", per-agent parameters {', '.join(columns)} from {args.given.get('params')}" if columns else "",
        args.semantics,
        f"; resumed at tick {resume_at:,}" if resume_at is not None else "",
    )


def ticked(metrics: Path, since: float) -> bool:
    """Whether the world wrote `metrics` (metrics.json) of one tick or more since `since` (a resumed
    run's folder holds the last)."""
    return metrics.exists() and metrics.stat().st_mtime >= since and json.loads(metrics.read_text())["ticks"] > 0


def launch(run: RunProcesses, folder: Path, view) -> tuple[int | None, bool, int | None]:
    """Start the services (and the live view), watch them until the world has ended, and end them
    together. Returns the exit code of a run that has no result (None: world and brain wrote
    theirs), whether it was interrupted (Ctrl-C or SIGTERM), and the recorder's exit code."""
    launcher, begun = Launcher(say_clean_ends=False), time.time()
    sigterm = signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM ends the run as Ctrl-C does
    interrupted = False
    try:
        try:
            for process in ([] if run.recording is None else [run.recorder]) + [run.world, run.brain]:
                launcher.start(process)
            if view is not None:
                view.start(folder / "viewer.log")
                view.show(lambda: all(map(launcher.running, launcher.children)))
            dead = launcher.watch(until="world", optional=("recorder",))  # a run goes on without a recording
        except KeyboardInterrupt:
            interrupted, dead = True, None
            log.warning("\ninterrupted: ending the run at the ticks done (Ctrl-C again to stop at once)")
            if "world" in launcher.children:  # as Ctrl-C: the world writes what it has, the brain saves
                launcher.stop("world")
            if not ticked(folder / "metrics.json", begun):  # a brain may not know the run: none to wait for
                failed(folder, "interrupted before the first tick")
                return 130, True, None
        if dead is not None:
            launcher.stop_all(timeout=STOP_S)  # the world writes its ticks done, the brain its learning
            failed(folder, dead)
            return 1, interrupted, None
        try:
            launcher.finish()  # the brain saves, the recorder writes the rest
        except KeyboardInterrupt:  # the first Ctrl-C as they do: they write what they have, as asked now
            if interrupted:
                raise
            interrupted = True
            log.warning("\ninterrupted: the brain and the recorder write what they have (Ctrl-C again to stop at once)")
            launcher.stop_all(timeout=STOP_S)
    except KeyboardInterrupt:
        log.error("stopped at once: no result written")
        failed(folder, "interrupted twice")
        return 130, True, None
    finally:
        launcher.stop_all()
        if view is not None:
            view.close()
        run.sockets.cleanup()
        signal.signal(signal.SIGTERM, sigterm)
    recorder = launcher.children.get("recorder")
    return None, interrupted, None if recorder is None else recorder.popen.returncode


if __name__ == "__main__":
    sys.exit(main())
