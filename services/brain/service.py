"""The brain service: `spikinglab brain` / `python -m services.brain`.

Reads:  spikinglab/<group>/sensors (Sensors), spikinglab/<group>/control (Control)
Writes: spikinglab/<group>/motor (Motor), liveliness spikinglab/<group>/alive/brain (or brain-<i>of<n>)

In lock-step with a world (lockstep.py: the protocol in node.py), or free-running on its own clock
with a robot (free_running.py, --clock). One brain serves a group's agents (or a shard of them):
a second one that finds it on the bus says so and exits.
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import dataclass
from pathlib import Path

from services.bus import keys
from services.bus.config import BusConfig, add_bus_args
from services.bus.transport import Bus, Presence
from services.options import Parser, at_least, number, output_file, output_folder, shard
from services.runtime import service_main

from .checkpoint import load_weights
from .circuit import CircuitError, load_circuit
from .engine_options import EngineOptions, add_engine_args, brain_params, engine_options_fit, learning_options_fit
from .free_running import FreeRunning, add_free_running_args, free_running_options
from .lockstep import LockStep
from .node import FREE_STATE_BATCH, BrainNode

log = logging.getLogger("spikinglab.brain")
WORLD_SHARDS_HELP = (
    "the world runs as N shards (world --shard I/N): each sends this brain the piece of its slice this "
    "brain serves, checked against a --params file (default 1; docs/shards.md)"
)
ALONE_AFTER_S = 1.0  # a brain of the same name not heard of within this long after joining the bus: none


def parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="spikinglab brain",
        description="The spiking-network brain, on the bus.",
        together=[
            engine_options_fit,
            learning_options_fit,
            lambda args: free_running_options(p, args),
            sharded_options_fit,
        ],
    )
    p.add_argument(
        "--circuit", default="insect", help="circuit name in services/brain/circuits/ or a .toml path (default insect)"
    )
    p.add_argument("--a-plus", type=number, help="A+ = A- of the learning neurons (default: the circuit's)")
    p.add_argument("--no-training", action="store_true", help="weights stay as they are")
    p.add_argument(
        "--params",
        type=Path,
        metavar="FILE.csv",
        help="per-agent parameters: a CSV file with a header of names (a_plus, a_minus, tau_plus, "
        "tau_minus, w_max, initial_weight, input_gain; the world's go to the world) and a row per "
        "agent of the whole population, or one row for all (docs/api.md); a shard takes its slice",
    )
    add_engine_args(p)
    p.add_argument(
        "--seed",
        type=at_least(0),
        help="the netlogo order's seed, agent a using seed + a (default: the world's seed, which its "
        "sensor messages carry, so that a run is the same in one process or across the bus)",
    )
    p.add_argument("--once", action="store_true", help="exit after one run ends (default: serve the next run)")
    p.add_argument(
        "--shard",
        type=shard,
        default=(1, 1),
        metavar="I/N",
        help="serve shard I of N of the population (the world, started with --shards N, sends each its "
        "slice of the agents; default 1/1: all of them)",
    )
    p.add_argument("--world-shards", type=at_least(1), default=1, metavar="N", help=WORLD_SHARDS_HELP)
    add_file_args(p)
    p.add_argument(
        "--publish-state",
        action="store_true",
        help="publish spikes and potentials of every tick, and the weights, in batches of 50 to 250 ticks "
        f"(fewer for more agents; {FREE_STATE_BATCH} free-running) for the recorder; the first tick "
        "waits until someone subscribes",
    )
    add_free_running_args(p)
    add_bus_args(p)
    return p


def add_file_args(p: argparse.ArgumentParser) -> None:
    """What the brain reads and writes besides the bus: weights, checkpoints, statistics."""
    p.add_argument("--load", type=Path, help="start from the weights in this checkpoint (.npz)")
    p.add_argument(
        "--save",
        type=output_file,
        help="write the final weights here (.npz) when a run ends (serving several runs: the last one's)",
    )
    p.add_argument(
        "--checkpoint",
        type=output_folder,
        metavar="DIR",
        help="keep the brain's whole state here whenever the world keeps a checkpoint (world "
        "--checkpoint), the last two per run: a resumed run goes back to them tick for tick",
    )
    p.add_argument(
        "--stats",
        type=output_file,
        help="write the rejected messages (and, free-running, the tick rate and lateness) here (JSON) when a run "
        "ends, and as the brain stops",
    )


@dataclass(frozen=True)
class BrainConfig:
    """The brain's options (parser()), typed: what run() and its parts take."""

    circuit: str
    a_plus: float | None
    no_training: bool
    params: Path | None
    engine: EngineOptions
    seed: int | None
    load: Path | None
    save: Path | None
    once: bool
    shard: tuple[int, int]
    world_shards: int
    checkpoint: Path | None
    stats: Path | None
    publish_state: bool
    clock: float  # free-running (robot) mode: add_free_running_args'
    stale_after: float
    no_realtime: bool
    bus: BusConfig


def run(config: BrainConfig, session) -> int:
    try:
        circuit = load_circuit(config.circuit)
        if config.a_plus is not None:
            circuit = circuit.with_learning_rate(config.a_plus)
        params = brain_params(config.params, circuit, config.a_plus) if config.params else None
        w_max = (params or {}).get("w_max")
        weights = load_weights(config.load, circuit, say=True, w_max=w_max) if config.load else None
    except (CircuitError, ValueError, OSError) as e:
        log.error("%s", e)
        return 2

    def new_node() -> BrainNode:  # one per run the brain serves
        return BrainNode(
            circuit,
            training=not config.no_training,
            weights=weights,
            checkpoints=config.checkpoint,
            shard=config.shard,
            world_shards=config.world_shards,
            params=params,
            free_running=bool(config.clock),
            seed=config.seed,
            semantics=config.engine.semantics,
            order=config.engine.order,
            netlogo_seed=config.engine.netlogo_seed,
        )

    group, service = config.bus.group, keys.brain_service(config.shard)
    if another_serving(session, group, service):
        log.error(
            "another brain already serves the agents of group %s%s on this bus (%s is alive): this one "
            "exits; stop that one first, or start this one with another --group",
            group,
            f", shard {config.shard[0]} of {config.shard[1]}" if config.shard[1] > 1 else "",
            keys.alive(group, service),
        )
        return 1
    robot = new_node() if config.clock else None  # free-running: one node, for the robot's runs
    if robot is not None:
        robot.compile_kernels()  # before the bus: docs/robot.md
    bus = Bus(session, group, service)
    try:
        return FreeRunning(config, bus, robot).run() if robot is not None else LockStep(config, bus, new_node).run()
    finally:
        bus.close()


def sharded_options_fit(args: argparse.Namespace) -> None:
    """A Parser's `together` check: what a brain shard, or the brain of a sharded world, does not do."""
    (i, n), shards = args.shard, args.world_shards
    if n > 1 and (args.publish_state or args.clock):
        option = "--publish-state" if args.publish_state else "--clock"
        raise ValueError(
            f"argument --shard: got '{i}/{n}' with {option}: a sharded brain serves a world in lock-step and does "
            f"not publish its state (the recorder takes one brain's; record the world, or run one brain): drop {option}"
        )
    given = (("--checkpoint", args.checkpoint), ("--clock", args.clock), ("--publish-state", args.publish_state))
    dropped = [option for option, value in given if value]
    if shards > 1 and dropped:
        raise ValueError(
            f"argument --world-shards: got {shards} with {' and '.join(dropped)}: a sharded world's brain keeps no "
            f"checkpoints, runs no robot and publishes no state: drop {' and '.join(dropped)}"
        )


def another_serving(session, group: str, service: str, within: float = ALONE_AFTER_S) -> bool:
    """Whether a brain of this name (group and shard) is alive on the bus: two would both answer
    the world. Asked before this one's own token; peers met through others take up to half a second
    to be known, so a session connected to anyone listens `within` seconds."""
    if not (any(True for _ in session.info.peers_zid()) or any(True for _ in session.info.routers_zid())):
        return False  # alone: no other brain to find (one that comes later finds this one)
    watch = Presence(session, group, service)
    try:
        return watch.wait(timeout=within)
    finally:
        watch.close()


def main(argv=None) -> int:
    return service_main("brain", parser(), run, argv, config=BrainConfig)


if __name__ == "__main__":
    sys.exit(main())
