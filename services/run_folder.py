"""A run folder of `spikinglab run` (runs/<id>/): taken for one run only, with the options the run
was started with (for --resume), its --params file, the checkpoints kept while it lasts, and
FAILED.txt when it has no result."""

from __future__ import annotations

import argparse
import json
import logging
import shutil
from pathlib import Path

from services import snapshots
from services.world.checkpoint import CHECKPOINT

log = logging.getLogger("spikinglab.run")
STARTED_WITH = "command.json"  # the options the run was started with, for --resume
KEPT_PARAMS = "params.csv"  # the --params file the run was started with, which world and brain read
RESULTS = (STARTED_WITH, "summary.json", "weights.npz")  # a folder with one of these holds a run


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


def take(folder: Path, args: argparse.Namespace, argv: list[str]) -> int | None:
    """Make `folder` the run's: a new run's (never over the learning of another run), or the
    interrupted run's that --resume goes on with. Keeps the options and the --params file of a new
    run (args.params then names the copy kept); returns the tick a resumed run goes on from."""
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
    folder.mkdir(parents=True, exist_ok=True)
    if args.resume:
        (folder / "FAILED.txt").unlink(missing_ok=True)  # it said how to go on: this is it
        return resume_at
    (folder / STARTED_WITH).write_text(json.dumps({"argv": argv}))
    if args.params:  # kept with the run, and read from there: what it was is what it stays
        shutil.copyfile(args.params, folder / KEPT_PARAMS)
        args.params = folder / KEPT_PARAMS
    return None


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
