"""The world's options (`spikinglab world`, `spikinglab run`) and the World they describe; no bus."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.options import add_netlogo_seed, at_least, shard_slice
from services.params import file_for_agents, side_of

from .netlogo_setup import spikinglab_setup
from .world import PRESETS, World, map_world, params_for


def add_preset(p) -> None:
    """--preset, the world's and the sweep's."""
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default="paper",
        help="rotation and move steps: paper (5 deg, 1 patch, default) or netlogo (4 deg, 0.4 patch)",
    )


@functools.cache
def file_digest(path: Path | None) -> str:
    """A file's SHA-256 (hex), "" for none: a map or parameter file is the same where its contents are.
    Read once in a process: what it was when the world loaded it, whatever becomes of it later."""
    return hashlib.sha256(path.read_bytes()).hexdigest() if path else ""


def shown_option(field: str, value) -> str:
    """An option's value as a message names it: a file's digest (the map's, the parameters') by its
    first 12 digits, as git shows a commit; "none" where unset."""
    return "none" if value in ("", None) else str(value)[:12] if field in ("map", "params") else str(value)


def add_learned_after(p) -> None:
    """--learned-after, the world's and the sweep's."""
    p.add_argument(
        "--learned-after",
        type=at_least(1),
        default=5000,
        metavar="TICKS",
        help="collision-free ticks that count as learned (default 5,000; docs/world.md)",
    )


def add_world_args(p: argparse.ArgumentParser, ticks: int = 40_000, least_ticks: int = 1, why: str = "") -> None:
    """The world's options; --ticks of at least `least_ticks` (`why`: what needs them)."""
    w = p.add_argument_group("world")
    w.add_argument("--ticks", type=at_least(least_ticks), default=ticks, help=f"ticks to run{why} (default {ticks:,})")
    w.add_argument(
        "--seed",
        type=at_least(0),
        default=0,
        help="world seed: maps and headings (agent a: the map of seed + a, a heading drawn from (seed, a))",
    )
    w.add_argument("--agents", type=at_least(1), default=1, help="insects stepped together (default 1)")
    w.add_argument("--shared", action="store_true", help="all agents share one arena (default: one each)")
    add_preset(w)
    w.add_argument("--map", type=Path, help="a text map file instead of the generated arena (docs/world.md)")
    add_netlogo_seed(
        w,
        "the arena and first heading that the SpikingLab source's setup makes after `random-seed N` "
        "(its own: 7850), for every agent (docs/netlogo-random.md)",
    )
    w.add_argument("--no-training", action="store_true", help="no push on noxious patches (test mode)")
    add_learned_after(w)
    w.add_argument(
        "--params",
        type=Path,
        metavar="FILE.csv",
        help="per-agent parameters: a CSV file with a header of names (rotation_step, move_step; the "
        "brain's, such as a_plus or w_max, go to the brain) and a row per agent, or one row for all "
        "(docs/api.md)",
    )


def check_shard_counts(agents: int, brain_shards: int, world_shard: tuple[int, int]) -> None:
    """ValueError, naming the option, where a brain or world shard would have no agent of its own."""
    if brain_shards > agents:
        raise ValueError(
            f"argument --shards: {brain_shards} brain shards of {agents:,} agents (--agents): "
            "at most one shard per agent"
        )
    if world_shard[1] > agents:
        raise ValueError(
            f"argument --shard: {world_shard[1]} world shards of {agents:,} agents (--agents), got "
            f"'{world_shard[0]}/{world_shard[1]}': at most one shard per agent"
        )


def check_shard_fits(shard: tuple[int, int], shared: bool) -> None:
    """ValueError, naming the option, where a world shard cannot step its slice alone."""
    if shard[1] > 1 and shared:
        raise ValueError(
            f"argument --shard: got '{shard[0]}/{shard[1]}' with --shared: the insects of a shared arena "
            "meet, so one world steps them all: drop --shard"
        )


def shards_fit(args: argparse.Namespace) -> None:
    """The world command's check of --shards and --shard against --agents and --shared, and of
    --shard against --checkpoint (Parser's `together`)."""
    check_shard_counts(args.agents, args.shards, args.shard)
    check_shard_fits(args.shard, args.shared)
    if args.shard[1] > 1 and args.checkpoint:
        raise ValueError(
            f"argument --shard: got '{args.shard[0]}/{args.shard[1]}' with --checkpoint: a sharded world "
            "keeps no checkpoints: drop --checkpoint"
        )


@dataclass(frozen=True)
class WorldOptions:
    """add_world_args' options, in the world's config (services.options.config_from; `run` makes
    one from its own options)."""

    ticks: int
    seed: int
    agents: int
    shared: bool
    preset: str
    map: Path | None
    no_training: bool
    learned_after: int
    params: Path | None
    netlogo_seed: int | None = None


def world_from(options: WorldOptions, shards: int = 1, shard: tuple[int, int] = (1, 1)) -> World:
    """The World the options describe, for a brain in `shards` (MapError / ValueError on a bad map
    or option); `shard` (I, N): only the agents shard_slice gives world shard I of N, each the same
    insect (arena, heading, parameters) as in the world of the whole population."""
    if options.ticks < 1 or options.agents < 1:
        raise ValueError("--ticks and --agents must be >= 1")
    check_shard_counts(options.agents, shards, shard)
    check_shard_fits(shard, options.shared)
    params = params_for(options.preset, learned_after=options.learned_after)
    grid = None
    if options.map:
        params, grid = map_world(options.map, params)
    if options.netlogo_seed is not None:
        if options.map:
            raise ValueError("--netlogo-seed and --map each give the arena: give one")
        setup = spikinglab_setup(options.netlogo_seed, params)
        params, grid = dataclasses.replace(params, start_heading=setup.heading), setup.grid
    columns = side_of(file_for_agents(options.params, options.agents) if options.params else {}, "world")
    lo, hi = shard_slice(options.agents, shard)
    try:
        return made_world(options, params, grid, columns, lo, hi, numbered=shard[1] > 1)
    except MemoryError as e:
        raise ValueError(
            f"--agents {hi - lo:,}: the world of so many does not fit in this machine's memory ({e})"
        ) from None


def made_world(options: WorldOptions, params, grid, columns: dict, lo: int, hi: int, numbered: bool) -> World:
    """World_from's world of agents lo..hi-1 of the population."""
    return World(
        params,
        agents=hi - lo,
        seed=options.seed,
        shared=options.shared,
        grid=grid,
        training=not options.no_training,
        numbers=np.arange(lo, hi) if numbered else None,
        agent_params={name: column if len(column) == 1 else column[lo:hi] for name, column in columns.items()},
    )
