"""A run folder of `spikinglab run` (runs/<id>/): taken for one run only, with the options the run
was started with (for --resume), the files it was given, the checkpoints kept while it lasts, and
FAILED.txt when it has no result."""

from __future__ import annotations

import argparse
import datetime
import fcntl
import itertools
import json
import logging
import os
import re
import shutil
from pathlib import Path

from services import snapshots
from services.brain.circuit import Circuit
from services.world.checkpoint import CHECKPOINT

log = logging.getLogger("spikinglab.run")
STARTED_WITH = "command.json"  # the options the run was started with, for --resume
# The files given to a run, kept in its folder under these names and read from there by world and
# brain: what they were is what they stay, and --resume finds them from any folder. The circuit
# keeps its file's name (a circuit without `name` is named after its file) in a folder of its own.
KEPT = {"params": "params.csv", "map": "map.txt", "load": "loaded-weights.npz", "circuit": "circuit"}
RESULTS = (STARTED_WITH, "summary.json", "weights.npz")  # a folder with one of these holds a run
RECORDING_PART = re.compile(r"recording(?:-from-tick(\d+))?\.rrd")  # recording_part's names: the tick it starts at


def new_folder(runs: Path, seed: int) -> Path:
    """A new run folder named by the date, time and seed (a run started in the same second with the
    same seed gets -2, -3, ...), made now so that no other run takes it."""
    name = f"{datetime.datetime.now():%Y%m%d-%H%M%S}-seed{seed}"
    runs.mkdir(parents=True, exist_ok=True)
    for n in itertools.count(1):
        folder = runs / (name if n == 1 else f"{name}-{n}")
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            continue
    raise AssertionError("unreachable")


class RunFolderError(ValueError):
    """The folder cannot take this run; the text says why and what to do."""


def checkpoint_tick(folder: Path) -> int | None:
    """The tick of the run's last checkpoint in `folder` (None: none kept, the run finished or never
    got to one). RunFolderError where the world's or the brain's checkpoint of it is damaged: a run
    resumed from it would go on without what it learned."""
    path = folder / "checkpoint" / CHECKPOINT
    if not path.exists():
        return None
    try:
        meta = snapshots.read(path)[1]
        tick, run = int(meta["tick"]), meta["run"]
        brain = folder / "checkpoint" / f"brain-{run}-tick{tick}.npz"
        if not brain.exists():  # kept after the world's: a run killed between the two has none
            raise ValueError(f"{brain}: not there (the brain's checkpoint of tick {tick:,})")
        snapshots.read(brain)
    except (ValueError, KeyError, TypeError) as e:
        raise RunFolderError(f"cannot resume the run in {folder}: {e}") from None
    return tick


def take(folder: Path, args: argparse.Namespace, argv: list[str], circuit: Circuit) -> int | None:
    """Make `folder` the run's, for as long as this process lives: a new run's (never over the
    learning of another run), or the interrupted run's that --resume goes on with. Keeps the options
    and the files given to a new run (KEPT; args then name the copies); returns the tick a resumed
    run goes on from."""
    folder.mkdir(parents=True, exist_ok=True)
    hold(folder)
    try:
        resume_at = checkpoint_tick(folder)
        interrupted = resume_at is not None
    except RunFolderError:
        if args.resume:
            raise
        resume_at, interrupted = None, True  # its checkpoint is damaged, but the run was interrupted
    if args.resume and resume_at is None:
        raise RunFolderError(
            f"nothing to resume in {folder}: no checkpoint (the run finished, or stopped before its first at "
            f"tick {args.checkpoint_every:,})"
        )
    if not args.resume and any((folder / name).exists() for name in RESULTS):
        how = f" (interrupted; go on with it: spikinglab run --resume {folder})" if interrupted else ""
        raise RunFolderError(f"{folder} holds a run already{how}: choose another --id")
    if args.resume:
        (folder / "FAILED.txt").unlink(missing_ok=True)  # it said how to go on: this is it
        return resume_at
    args.given = given_files(args)
    for option, given in args.given.items():
        kept = folder / kept_name(option, given)
        kept.parent.mkdir(exist_ok=True)
        shutil.copyfile(circuit.source if option == "circuit" else given, kept)  # a circuit given by name too
        setattr(args, option, kept)
    (folder / STARTED_WITH).write_text(json.dumps({"argv": argv}))  # last: from here on the folder holds a run
    return None


def given_files(args: argparse.Namespace) -> dict[str, str]:
    """The files given to a run (KEPT's options), as given."""
    return {option: str(getattr(args, option)) for option in KEPT if getattr(args, option)}


def kept_name(option: str, given: str | Path) -> Path:
    """Where in a run folder the file given as `option` is kept."""
    return Path(KEPT[option], Path(given).stem + ".toml") if option == "circuit" else Path(KEPT[option])


def kept_files(folder: Path, options: argparse.Namespace) -> None:
    """The options of a resumed run name the files kept in its folder (those its start kept);
    `options.given`: the files as they were given."""
    options.given = given_files(options)
    for option in options.given:
        kept = folder / kept_name(option, options.given[option])
        if kept.exists():
            setattr(options, option, kept)


def hold(folder: Path) -> None:
    """A lock on `folder` until this process ends (its descriptor is left open): a second run in
    the same folder at the same time is refused. (A file system without locks: no lock.)"""
    descriptor = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(descriptor)
        raise RunFolderError(f"{folder} is in use by another spikinglab run now: choose another --id") from None
    except OSError as e:
        os.close(descriptor)
        log.warning("%s: cannot be locked (%s): nothing keeps another run out of it", folder, e.strerror or e)


def recording_part(folder: Path, resume_at: int | None) -> Path:
    """The recording of a run's part: recording.rrd from its start, recording-from-tickN.rrd from a
    resume at tick N (the viewer shows the parts as one recording)."""
    return folder / ("recording.rrd" if resume_at is None else f"recording-from-tick{resume_at}.rrd")


def recording_parts(folder: Path) -> dict[Path, int]:
    """The run's recording by part, the first first (not an earlier try of a part, kept as
    .previous.rrd): {path: the tick it starts at}."""
    parts = {path: RECORDING_PART.fullmatch(path.name) for path in folder.glob("recording*.rrd")}
    return dict(sorted(((path, int(m.group(1) or 0)) for path, m in parts.items() if m), key=lambda part: part[1]))


def started_with(folder: Path) -> list[str]:
    """The options the run in `folder` was started with; RunFolderError if it is no run folder."""
    try:
        return json.loads((folder / STARTED_WITH).read_text())["argv"]
    except (OSError, ValueError, KeyError, TypeError):
        raise RunFolderError(f"{folder} is not a run folder of `spikinglab run` (no readable {STARTED_WITH})") from None


def resume_hint(folder: Path) -> str:
    """How an interrupted run goes on, when it kept a checkpoint."""
    try:
        tick = checkpoint_tick(folder)
    except RunFolderError as e:
        return f"; {e}"
    return "" if tick is None else f"; go on from its checkpoint at tick {tick:,}: spikinglab run --resume {folder}"


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
