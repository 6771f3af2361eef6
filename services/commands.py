"""Every `spikinglab` command, and which of them a launch file can start: the one registry that the
CLI (spikinglab/cli.py) and the launcher (services/launch.py) read.

It lives here, not in the `spikinglab` front package, because the launcher is in `services` and
`services` does not import the front. It names modules and imports none of them, so that reading
it costs nothing: a command imports only its own module (the gateway on a robot's small computer
never imports the engine or the viewer).
"""

from __future__ import annotations

from dataclasses import dataclass

# services.launch.spawn sets it in a process it starts: the starter's pid (services.runtime.end_with_parent)
PARENT = "SPIKINGLAB_PARENT"


@dataclass(frozen=True)
class Command:
    """`module` has main(argv); a `launchable` one also has parser() and is a launch file's
    `service`; an `endless` one serves the others and never ends by itself (stopped after them)."""

    module: str
    about: str
    launchable: bool = False
    endless: bool = False


BENCHMARKS = {  # `spikinglab bench NAME`
    "engine": "spikinglab.bench.engine",
    "loop": "spikinglab.bench.loop",
    "scale": "spikinglab.bench.scale",
    "recorder": "spikinglab.bench.recorder",
    "gateway": "spikinglab.bench.gateway",
    "table1": "spikinglab.bench.table1",
    "robot": "spikinglab.bench.robot",
    "fuzz": "spikinglab.bench.fuzz",
    "soak": "spikinglab.bench.soak",
    "gpu": "spikinglab.bench.gpu",
}

COMMANDS = {
    "run": Command(
        "services.run", "train the insect: world, brain and recorder as processes on the bus (the main job)"
    ),
    "launch": Command("services.launch", "start the services a launch file names (simulation, robot, remote-...)"),
    "brain": Command("services.brain.service", "the brain service on the bus", launchable=True),
    "world": Command("services.world.service", "the world service on the bus", launchable=True),
    "gateway": Command(
        "services.ev3_gateway.service", "the robot side: a LEGO EV3 (or a simulated one) on the bus", launchable=True
    ),
    "fake-brick": Command(
        "services.ev3_gateway.fake_brick",
        "a fake EV3 brick on loopback that speaks the brick's WiFi protocol, for the gateway",
        launchable=True,
        endless=True,
    ),
    "record": Command("services.recorder.service", "record a run to a Rerun file (.rrd)", launchable=True),
    "screenshot": Command("services.recorder.screenshot", "a PNG of a recording's replay, rendered headless"),
    "router": Command(
        "services.router", "a Zenoh router, for brain and world on different machines", launchable=True, endless=True
    ),
    "certs": Command("services.certs", "certificates and configs for a bus with mutual TLS and access control"),
    "sweep": Command("services.sweep", "the paper's Table 1: learning time for A+ = A- over seeds"),
    "conditioning": Command("services.brain.conditioning", "classical conditioning demo on fig. 2 and fig. 4"),
    "bench": Command("spikinglab.bench", "benchmarks and experiments: bench " + " | ".join(BENCHMARKS)),
}

SERVICES = {name: c.module for name, c in COMMANDS.items() if c.launchable}  # a launch file's `service` -> module
ENDLESS = frozenset(name for name, c in COMMANDS.items() if c.endless)
