"""The engine's options, shared by `brain`, `run` and `sweep`: the semantics and order options, and
the --params file checked against a circuit. No bus here: `sweep` and `run` import this module."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from services.options import add_netlogo_seed
from services.params import AgentValueError, agent_line, file_rows, read_params, side_of

from .build import DEFAULT_SEMANTICS, ORDERS, SEMANTICS, check_options, learning_tables


def add_engine_args(p: argparse.ArgumentParser) -> None:
    """The engine's semantics options."""
    p.add_argument(
        "--semantics",
        choices=SEMANTICS,
        default=DEFAULT_SEMANTICS,
        help=f"phased: five phases, a delay of d is exactly d; netlogo: the original NetLogo engine's "
        f"turns (docs/tick.md) (default {DEFAULT_SEMANTICS})",
    )
    p.add_argument(
        "--order",
        choices=ORDERS,
        default="random",
        help="netlogo: neurons each tick in a seeded random order (as NetLogo's ask), in file order, or "
        "netlogo-stream: drawn from NetLogo's own stream after the source's setup, as the source draws it "
        "(needs --netlogo-seed; docs/netlogo-random.md)",
    )
    try:  # `run` and `sweep` declare it with the world's options: there it is the same option
        add_netlogo_seed(
            p,
            "order netlogo-stream: NetLogo's stream as the SpikingLab source's setup leaves it after "
            "`random-seed N` (the world's --netlogo-seed: its arena)",
        )
    except argparse.ArgumentError:
        pass


def engine_options_fit(args: argparse.Namespace) -> None:
    """A Parser's `together` check: ValueError where the engine options do not go together
    (--order netlogo-stream without --semantics netlogo and --netlogo-seed)."""
    check_options(1, args.semantics, args.order, (), args.netlogo_seed)


def learning_options_fit(args: argparse.Namespace) -> None:
    """A Parser's `together` check: --a-plus would be ignored with --no-training."""
    if args.a_plus is not None and args.no_training:
        raise ValueError("argument --a-plus: a learning rate, but --no-training keeps the weights as they are")


@dataclass(frozen=True)
class EngineOptions:
    """add_engine_args' options, in the brain's config (services.options.config_from)."""

    semantics: str
    order: str
    netlogo_seed: int | None = None


def brain_params(path: Path, circuit, a_plus: float | None = None) -> dict:
    """The --params file's columns (all of them: a shard slices them by its sensors' agents), checked
    against the circuit before any run: ValueError for a value it cannot take (a w_max below its
    initial weights), or for a learning rate that --a-plus (`a_plus`) sets too."""
    columns = read_params(path)
    both = [name for name in ("a_plus", "a_minus") if name in columns]
    if a_plus is not None and both:
        raise ValueError(
            f"argument --a-plus: sets A+ and A- of every agent, and parameter file {path} sets "
            f"{' and '.join(both)} per agent: give one of them"
        )
    try:
        learning_tables(circuit, side_of(columns, "brain"), file_rows(columns))
    except AgentValueError as e:
        raise ValueError(f"parameter file {path}, line {agent_line(path, e.agent)}: {e}") from None
    except ValueError as e:
        raise ValueError(f"parameter file {path}: {e}") from None
    return columns
