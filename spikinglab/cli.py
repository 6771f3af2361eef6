"""`spikinglab <command>`: one entry point, each command a module with its own main(argv)."""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "run": ("services.run", "train the insect: world, brain and recorder as processes on the bus (the main job)"),
    "launch": ("services.launch", "start the services a launch file names (simulation, robot, remote-...)"),
    "brain": ("services.brain.service", "the brain service on the bus"),
    "world": ("services.world.service", "the world service on the bus"),
    "gateway": ("services.ev3_gateway.service", "the robot side: a LEGO EV3 (or a simulated one) on the bus"),
    "record": ("services.recorder.service", "record a run to a Rerun file (.rrd)"),
    "screenshot": ("services.recorder.screenshot", "a PNG of a recording's replay, rendered headless"),
    "router": ("services.router", "a Zenoh router, for brain and world on different machines"),
    "certs": ("services.certs", "certificates and configs for a bus with mutual TLS and access control"),
    "sweep": ("services.sweep", "the paper's Table 1: learning time for A+ = A- over seeds"),
    "conditioning": ("services.brain.conditioning", "classical conditioning demo on fig. 2 and fig. 4"),
    "bench": (
        None,
        "benchmarks and experiments: bench engine | loop | scale | recorder | gateway | table1 | robot | fuzz | soak",
    ),
}
BENCHMARKS = {
    "engine": "spikinglab.bench.engine",
    "loop": "spikinglab.bench.loop",
    "scale": "spikinglab.bench.scale",
    "recorder": "spikinglab.bench.recorder",
    "gateway": "spikinglab.bench.gateway",
    "table1": "spikinglab.bench.table1",
    "robot": "spikinglab.bench.robot",
    "fuzz": "spikinglab.bench.fuzz",
    "soak": "spikinglab.bench.soak",
}


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
    lines += [f"  {name:14s} {about}" for name, (_, about) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return
    if argv[0] == "--version":
        print(f"spikinglab {version()}")
        return
    name, rest = argv[0], argv[1:]
    if name == "bench":
        if not rest or rest[0] not in BENCHMARKS:
            print(f"spikinglab bench: which benchmark? one of {', '.join(BENCHMARKS)}", file=sys.stderr)
            sys.exit(2)
        module, rest = BENCHMARKS[rest[0]], rest[1:]
    elif name in COMMANDS:
        module = COMMANDS[name][0]
    else:
        print(f"spikinglab: unknown command {name!r} (spikinglab --help lists the commands)", file=sys.stderr)
        sys.exit(2)
    code = importlib.import_module(module).main(rest)
    sys.exit(code if isinstance(code, int) else 0)  # benchmarks return their figures


if __name__ == "__main__":
    main()
