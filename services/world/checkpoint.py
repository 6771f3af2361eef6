"""The world's whole-run checkpoints (world --checkpoint DIR): kept every --checkpoint-every
ticks, and resumed by the same command with the same options."""

from __future__ import annotations

from pathlib import Path

from services import snapshots
from services.bus.schemas import RUN_ID

from .options import WorldOptions, file_digest, shown_option
from .results import Trajectory
from .world import World

CHECKPOINT = "world.npz"  # in --checkpoint DIR: the world of one run, at its last checkpoint
# a checkpoint becomes CHECKPOINT once the brain has answered its tick, so has kept its own there:
# a world that dies in between leaves the previous pair, never a world without its brain
PENDING = "world-pending.npz"


def run_options(options: WorldOptions) -> dict:
    """The options that make a run what it is: a checkpoint resumes only under the same ones."""
    return {
        "ticks": options.ticks,
        "seed": options.seed,
        "agents": options.agents,
        "shared": options.shared,
        "preset": options.preset,
        "map": file_digest(options.map) or None,  # its contents, wherever the file lies now
        "netlogo_seed": options.netlogo_seed,
        "no_training": options.no_training,
        "learned_after": options.learned_after,
    }


def option(key: str) -> str:
    return "--map (its file's SHA-256)" if key == "map" else f"--{key.replace('_', '-')}"


def keep_checkpoint(folder: Path, options: WorldOptions, world: World, trajectory: Trajectory, run_id: str) -> None:
    """The world as it is now, kept as PENDING until the brain has kept its own (then CHECKPOINT)."""
    arrays = {
        **{f"world.{k}": v for k, v in world.snapshot().items()},
        **{f"trajectory.{k}": v for k, v in trajectory.arrays().items()},
    }
    snapshots.write(folder / PENDING, arrays, {"run": run_id, "tick": world.tick, "options": run_options(options)})


def resume(folder: Path, options: WorldOptions, world: World, trajectory: Trajectory) -> str | None:
    """The run kept in `folder` (--checkpoint), restored into `world` and `trajectory` (None:
    nothing kept). ValueError when it is not a checkpoint of a run with these options."""
    path = folder / CHECKPOINT
    if not path.exists():
        return None
    arrays, meta = snapshots.read(path)
    kept, wanted = meta.get("options", {}), run_options(options)
    differ = [
        f"{option(k)} {shown_option(k, kept.get(k))} there, {shown_option(k, v)} here"
        for k, v in wanted.items()
        if kept.get(k) != v
    ]
    if differ:
        raise ValueError(
            f"{path} holds run {meta.get('run')} at tick {meta.get('tick')} made with other options "
            f"({'; '.join(differ)}): resume it with those, or give another --checkpoint folder"
        )
    if not RUN_ID.fullmatch(str(meta.get("run"))):
        raise ValueError(f"{path}: not a world checkpoint (no run id in it)")
    world.restore({k.removeprefix("world."): v for k, v in arrays.items() if k.startswith("world.")})
    snapshots.copy_into(
        trajectory.arrays(),
        {k.removeprefix("trajectory."): v for k, v in arrays.items() if k.startswith("trajectory.")},
        str(path),
    )
    return meta["run"]


def confirm(folder: Path) -> None:
    """The brain has answered the tick of the checkpoint kept last, so has kept its own: the run
    resumes from this one."""
    if (folder / PENDING).exists():
        (folder / PENDING).replace(folder / CHECKPOINT)


def forget(folder: Path) -> None:
    """The run is whole: nothing is left to resume."""
    (folder / CHECKPOINT).unlink(missing_ok=True)
    (folder / PENDING).unlink(missing_ok=True)
