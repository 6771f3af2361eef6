"""`spikinglab <command>`: one entry point, each command a module with its own main(argv), named
in the registry (services/commands.py)."""

from __future__ import annotations

import importlib
import os
import signal
import sys

from services.commands import BENCHMARKS, COMMANDS
from services.interrupts import take_interrupts


def version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("spikinglab")
    except PackageNotFoundError:  # run from a checkout that was never installed
        return "unknown (not installed)"


def usage() -> str:
    lines = [
        "usage: spikinglab <command> [options]   (spikinglab <command> --help for its options; spikinglab --version)",
        "",
    ]
    lines += [f"  {name:14s} {command.about}" for name, command in COMMANDS.items()]
    return "\n".join(lines)


def command_module(name: str, module: str):
    """The module of command `name`; one line and exit 2 where a package it needs is not installed."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:  # an install without it, such as the gateway's alone (docs/robot.md)
        if not e.name or e.name.partition(".")[0] in ("services", "spikinglab"):
            raise
        print(
            f"spikinglab {name}: needs the package {e.name.partition('.')[0]}, which this install leaves out "
            "(the gateway alone installs only what the gateway needs: docs/robot.md)",
            file=sys.stderr,
        )
        sys.exit(2)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return
    if argv[0] == "--version":
        print(f"spikinglab {version()}")
        return
    take_interrupts(signal.SIGTERM)  # Ctrl-C and SIGTERM: KeyboardInterrupt, never inside a kernel's compile
    name, rest = argv[0], argv[1:]
    if name == "bench":
        if rest[:1] in (["-h"], ["--help"]):
            print(f"usage: spikinglab bench {{{','.join(BENCHMARKS)}}} [options]   (spikinglab bench NAME --help)")
            return
        if not rest or rest[0] not in BENCHMARKS:
            said = f"no benchmark {rest[0]!r}" if rest else "which benchmark?"
            print(f"spikinglab bench: {said} (one of {', '.join(BENCHMARKS)})", file=sys.stderr)
            sys.exit(2)
        module, rest = BENCHMARKS[rest[0]], rest[1:]
    elif name in COMMANDS:
        module = COMMANDS[name].module
    else:
        print(f"spikinglab: unknown command {name!r} (spikinglab --help lists the commands)", file=sys.stderr)
        sys.exit(2)
    try:
        code = command_module(name, module).main(rest)
        sys.stdout.flush()  # a reader gone shows here, not as Python's error at its exit
    except KeyboardInterrupt:  # one the command does not take itself, its modules loading too: a line, not a traceback
        print(f"spikinglab {name}: interrupted", file=sys.stderr)
        sys.exit(130)
    except BrokenPipeError:  # whoever read the output stopped (`| head`): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # the exit's flush would fail again
        sys.exit(1)
    sys.exit(code if isinstance(code, int) else 0)  # benchmarks return their figures


if __name__ == "__main__":
    main()
