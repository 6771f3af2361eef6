"""The world's options (`spikinglab world`, `spikinglab run`) and the World they describe; no bus."""

from __future__ import annotations

import argparse
from pathlib import Path

from services.options import at_least
from services.params import file_for_agents, side_of

from .world import PRESETS, World, map_world, params_for


def add_world_args(p: argparse.ArgumentParser) -> None:
    w = p.add_argument_group("world")
    w.add_argument("--ticks", type=at_least(1), default=40_000, help="ticks to run (default %(default)s)")
    w.add_argument("--seed", type=at_least(0), default=0, help="world seed: maps and headings (agent a uses seed + a)")
    w.add_argument("--agents", type=at_least(1), default=1, help="insects stepped together (default 1)")
    w.add_argument("--shared", action="store_true", help="all agents share one arena (default: one each)")
    w.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default="paper",
        help="rotation and move steps: paper (5 deg, 1 patch, default) or netlogo (4 deg, 0.4 patch)",
    )
    w.add_argument("--map", type=Path, help="a text map file instead of the generated arena (docs/world.md)")
    w.add_argument("--no-training", action="store_true", help="no push on noxious patches (test mode)")
    w.add_argument(
        "--learned-after",
        type=at_least(1),
        default=5000,
        help="collision-free ticks that count as learned (default 5,000)",
    )
    w.add_argument(
        "--params",
        type=Path,
        metavar="FILE.csv",
        help="per-agent parameters: a CSV file with a header of names (rotation_step, move_step; the "
        "brain's, such as a_plus or w_max, go to the brain) and a row per agent, or one row for all "
        "(docs/api.md)",
    )


def world_from_args(args: argparse.Namespace) -> World:
    """The World the options describe (MapError / ValueError on a bad map or option)."""
    if args.ticks < 1 or args.agents < 1:
        raise ValueError("--ticks and --agents must be >= 1")
    if getattr(args, "shards", 1) > args.agents:
        raise ValueError(f"--shards {args.shards}: more brain shards than agents ({args.agents})")
    params = params_for(args.preset, learned_after=args.learned_after)
    grid = None
    if args.map:
        params, grid = map_world(args.map, params)
    columns = file_for_agents(args.params, args.agents) if args.params else {}
    return World(
        params,
        agents=args.agents,
        seed=args.seed,
        shared=args.shared,
        grid=grid,
        training=not args.no_training,
        agent_params=side_of(columns, "world"),
    )
