"""Command-line options shared by every command: a parser whose errors are one line, and checks
that refuse a bad value before anything starts (argparse names the option in the message)."""

from __future__ import annotations

import argparse
import dataclasses
import ipaddress
import math
import os
import sys
import tempfile
import types
import typing
from pathlib import Path

C = typing.TypeVar("C")


class UsageError(Exception):
    """A usage error from a Parser with exit_on_error = False (a launch file's options)."""


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the option and what was wrong (exit 2), and
    options are spelled out (no abbreviations: `--tick` is not silently `--ticks`). With
    exit_on_error = False, errors raise (argparse.ArgumentError or UsageError) instead. `together`:
    checks of the parsed options that raise ValueError, naming the option, where values that are
    each fine do not go together (`--shard 1/9` of `--agents 4`): usage errors too."""

    def __init__(self, *args, together: typing.Sequence[typing.Callable[[argparse.Namespace], None]] = (), **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self.together = together

    def parse_known_args(self, args=None, namespace=None):  # parse_args' too
        args = sys.argv[1:] if args is None else list(args)
        self.refuse_dashed_values(args)
        parsed, extras = super().parse_known_args(args, namespace)
        for check in self.together:
            try:
                check(parsed)
            except ValueError as e:
                self.error(str(e))
        return parsed, extras

    def refuse_dashed_values(self, args: list[str]) -> None:
        """argparse takes a value that begins with '-' and is not a plain negative number
        (`--shard -1/2`, `--sigma -1e-3` before Python 3.14) for an option, and says only "expected
        one argument": say how to give it. Up to a `--`; a value with a space argparse takes as one."""
        args = args[: args.index("--")] if "--" in args else args
        for option, value in zip(args, args[1:]):
            action = self._option_string_actions.get(option)
            if (
                action is not None
                and action.nargs in (None, "+")
                and value.startswith("-")
                and not value.startswith("--")  # an option, misspelt or not: argparse says which
                and value != "-"  # a value for argparse: standard input, say
                and " " not in value
                and not self._negative_number_matcher.match(value)
            ):
                self.error(f"argument {option}: its value {value!r} begins with '-', so write {option}={value}")

    def mode_defaults(self, args: argparse.Namespace, mode: str, options: dict) -> None:
        """Options that serve some modes of a command only: declared with no default, so that one
        given in a mode it does not serve is a usage error rather than ignored; each left out takes
        its default here. `mode`: the flag that chose the mode ("--robot"), or "" for none;
        `options`: {"--option": (default, the modes it serves)}. The help states the defaults."""
        for option, (default, modes) in options.items():
            name = option[2:].replace("-", "_")
            if getattr(args, name) is None:
                setattr(args, name, default)
            elif mode not in modes:
                self.error(
                    f"argument {option}: " + (f"not with {mode}" if "" in modes else f"only with {' or '.join(modes)}")
                )

    def error(self, message: str):
        if not self.exit_on_error:
            raise UsageError(message)
        print(f"{self.prog}: {message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(2)


def whole_number(text: str, what: str = "a whole number") -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None


def add_netlogo_seed(p, help: str) -> None:
    """--netlogo-seed N: a seed of NetLogo's `random-seed`, a Java int (a brain's agent a takes
    N + a, whose range the brain checks where it knows the agents)."""
    p.add_argument("--netlogo-seed", type=whole_within(-(2**31), 2**31 - 1, " (a Java int)"), metavar="N", help=help)


def at_least(minimum: int):
    """An int option of at least `minimum`."""
    return whole_within(minimum, None)


def whole_within(lowest: int, highest: int | None, why: str = ""):
    """An int option of at least `lowest` and at most `highest` (None: no upper bound); `why` says
    what bounds it from above (e.g. " (100 years)")."""

    def check(text: str) -> int:
        value = whole_number(text)
        if value < lowest:
            raise argparse.ArgumentTypeError(f"must be at least {lowest:,}, got {value:,}")
        if highest is not None and value > highest:
            raise argparse.ArgumentTypeError(f"must be at most {highest:,}{why}, got {value:,}")
        return value

    return check


def ip_address(text: str) -> str:
    """An address to listen on: an IP address."""
    try:
        return str(ipaddress.ip_address(text))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not an IP address: e.g. 127.0.0.1 (this machine only) or 0.0.0.0 (every interface)"
        ) from None


def port(text: str) -> int:
    """A TCP port option, 1..65535."""
    value = whole_number(text, "a port number")
    if not 0 < value < 65536:
        raise argparse.ArgumentTypeError(f"a port is 1..65535, got {value}")
    return value


def number(text: str) -> float:
    """A finite float option."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text}")
    return value


def positive(text: str) -> float:
    """A float option above 0."""
    value = number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a number above 0, got {text}")
    return value


def number_within(lowest: float, highest: float, why: str = ""):
    """A float option within lowest .. highest; `why` says what the range is."""

    def check(text: str) -> float:
        value = number(text)
        if not lowest <= value <= highest:
            raise argparse.ArgumentTypeError(f"must be {lowest:g} .. {highest:g}{why}, got {text}")
        return value

    return check


def not_negative(text: str) -> float:
    """A float option of 0 or more (0 meaning none or no limit, as each option's help says)."""
    value = number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text}")
    return value


def _unwritable(folder: Path) -> str | None:
    """Why `folder` cannot be written to or made, or None: tried with a folder made and removed in
    the nearest one that exists (a permission check alone passes for root where nothing can be made)."""
    for place in (folder, *folder.parents):
        if place.exists():
            if not place.is_dir():
                return f"{place} is a file, not a folder"
            try:
                os.rmdir(tempfile.mkdtemp(dir=place))
            except OSError as e:
                return f"nothing can be written in {place} ({e.strerror})"
            return None
    return None


def folder_path(text: str) -> Path:
    """A folder's path, not "" (which would be the current folder unasked)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder, got an empty name (the current one: give .)")
    return Path(text)


def output_folder(text: str) -> Path:
    """A folder option that is written to: one that exists and takes files, or one that can be made."""
    path = folder_path(text)
    why = _unwritable(path)
    if why:
        raise argparse.ArgumentTypeError(f"cannot write to the folder {text}: {why}")
    return path


def output_file(text: str) -> Path:
    """A file option that is written to: not a folder, and its folder exists and takes files or can be made."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a file name, got an empty one")
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder; expected a file name")
    why = _unwritable(path.parent)
    if why:
        raise argparse.ArgumentTypeError(f"cannot write {text}: {why}")
    return path


def folder_name(text: str) -> str:
    """A folder's own name (--id): not a path, so that it stays inside the folder it goes in."""
    if text in ("", ".", "..") or "/" in text or "\\" in text:
        raise argparse.ArgumentTypeError(f"expected a folder name, not a path: got {text!r}")
    return text


def agent_list(text: str) -> tuple[int, ...]:
    """Agent numbers separated by commas (`0`, `0,3,7`): at least one."""
    try:
        agents = tuple(int(a) for a in text.split(",") if a.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected agent numbers separated by commas, e.g. 0,3,7; got {text!r}"
        ) from None
    if not agents:
        raise argparse.ArgumentTypeError(f"name at least one agent, e.g. 0 or 0,3,7; got {text!r}")
    if any(a < 0 for a in agents):
        raise argparse.ArgumentTypeError(f"agent numbers start at 0, got {text!r}")
    return agents


def shard(text: str) -> tuple[int, int]:
    """ "I/N": shard I of N (1 <= I <= N)."""
    i, slash, n = text.partition("/")
    try:
        i, n = int(i), int(n)
    except ValueError:
        i = n = 0
    if not slash or not 1 <= i <= n:
        raise argparse.ArgumentTypeError(f"must be I/N with 1 <= I <= N (e.g. 2/3), got {text!r}")
    return i, n


def shard_slice(agents: int, shard: tuple[int, int]) -> tuple[int, int]:
    """The agents shard (I, N) of a population serves: first, last + 1. The N slices follow one
    another and differ in size by one agent at most (brain --shard I/N, world --shards N)."""
    i, n = shard
    return agents * (i - 1) // n, agents * i // n


def shards_meet(agents: int, world_shard: tuple[int, int], brain_shard: tuple[int, int]) -> tuple[int, int]:
    """The agents (first, last + 1) that world shard (I, N) steps and brain shard (J, M) serves:
    where their slices meet (first == last + 1: none). World and brain slices need not align: a
    brain shard serves a piece of every world shard's slice its own meets."""
    w, b = shard_slice(agents, world_shard), shard_slice(agents, brain_shard)
    lo = max(w[0], b[0])
    return lo, max(lo, min(w[1], b[1]))


def config_from(namespace: argparse.Namespace, cls: type[C], whole: bool = True) -> C:
    """The frozen dataclass `cls` made from parsed options, field by field; a field that is itself a
    dataclass (a group of options that several commands add: the bus's, the world's) is made from
    the same options. The parser is where options are declared; the dataclass names their types.
    TypeError, naming it, for a field without its option, a value not of its field's type, and (with
    `whole`: a service's config) an option without its field."""
    given = vars(namespace)
    config = _made(given, cls)
    unread = set(given) - option_names(cls)
    if whole and unread:
        raise TypeError(f"{cls.__name__} has no field for the option(s) {', '.join(sorted(unread))}")
    return config


def option_names(cls: type) -> set[str]:
    """The options a config dataclass holds, its nested groups' too."""
    names: set[str] = set()
    for name, kind in _fields(cls):
        names |= option_names(kind) if _is_group(kind) else {name}
    return names


def _made(given: dict, cls: type[C]) -> C:
    values = {}
    for name, kind in _fields(cls):
        if _is_group(kind):
            values[name] = _made(given, kind)
        elif name not in given:
            raise TypeError(f"{cls.__name__}.{name} has no option")
        elif not _fits(given[name], kind):
            raise TypeError(f"{cls.__name__}.{name} is {kind}, the option gives {given[name]!r}")
        else:
            values[name] = given[name]
    return cls(**values)


def _fields(cls: type) -> list[tuple[str, typing.Any]]:
    """A dataclass's fields: (name, type), the types resolved (they are text in a module that
    imports annotations from __future__)."""
    hints = typing.get_type_hints(cls)
    return [(f.name, hints[f.name]) for f in dataclasses.fields(cls)]


def _is_group(kind) -> bool:
    return isinstance(kind, type) and dataclasses.is_dataclass(kind)


def _fits(value, kind) -> bool:
    """Whether `value` is of type `kind` (its outer class: list[str] checks for a list)."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, k) for k in typing.get_args(kind))
    if kind is None or kind is type(None):
        return value is None
    outer = origin or kind
    return isinstance(value, (int, float) if outer is float else outer)  # an int is a float (PEP 484)
