"""Gateway benchmark: the robot chain against the fake brick (which answers at once).

polls/s:          the gateway reading the brick as fast as the link allows (no brain)
sensor-to-motor:  an obstacle appears 3 cm ahead on the brick -> the gateway's next poll -> pain ->
                  the free-running brain -> ROTATE -> the spin command on the brick; median of trials
brain:            its achieved tick rate and p99 lateness while doing that, at --clock Hz
The last line printed is JSON. Run: `spikinglab bench gateway` or `python -m spikinglab.bench.gateway`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from services.ev3_gateway.fake_brick import FakeBrick
from services.launch import local_endpoints, spawn
from services.options import Parser, at_least, positive


def polls_per_s(seconds: float) -> float:
    with FakeBrick(), tempfile.TemporaryDirectory() as tmp:
        (gateway_ep,), sockets = local_endpoints("gateway")
        with sockets:
            gateway = spawn(
                "gateway",
                ["--listen", gateway_ep, "--duration", seconds, "--stats", Path(tmp) / "g.json"],
                subprocess.DEVNULL,
            )
            gateway.wait(seconds + 30)
        return json.loads((Path(tmp) / "g.json").read_text())["polls"] / seconds


def gateway_and_brain(
    gateway_ep: str,
    brain_ep: str,
    hz: float,
    gateway: list | tuple = (),
    brain: list | tuple = (),
    logs: Path | None = None,
    cwd: Path | None = None,
) -> tuple[subprocess.Popen, subprocess.Popen]:
    """The robot chain's processes: the gateway listening on `gateway_ep` and a free-running brain
    at `hz` Hz on `brain_ep` driving it, each with its further options; their output into
    logs/gateway.log and logs/brain.log (no `logs`: discarded)."""

    def output(name: str) -> Path | int:
        return logs / f"{name}.log" if logs else subprocess.DEVNULL

    return (
        spawn("gateway", ["--listen", gateway_ep, *gateway], output("gateway"), cwd),
        spawn("brain", ["--listen", brain_ep, "--connect", gateway_ep, "--clock", hz, *brain], output("brain"), cwd),
    )


def chain(trials: int, hz: float, max_polls: float = 0) -> tuple[list[float], dict]:
    wait_s = 2 + 100 / hz  # the chain from the sensor to a spin takes tens of the brain's ticks
    # the brain gets a core of its own; the gateway polls flat out against a brick that answers at
    # once, so it and the brick (threads of this process) share the other
    os.sched_setaffinity(0, {0})
    with FakeBrick() as brick, tempfile.TemporaryDirectory() as tmp:
        (gateway_ep, brain_ep), sockets = local_endpoints("gateway", "brain")
        with sockets:
            gateway, brain = gateway_and_brain(
                gateway_ep,
                brain_ep,
                hz,
                ["--cpu", 0, "--max-polls", max_polls],
                ["--stats", Path(tmp) / "b.json", "--cpu", 1],
            )
            latencies = []
            try:
                deadline = time.monotonic() + 60
                while not brick.commands and time.monotonic() < deadline:  # running: the first MOVE
                    time.sleep(0.01)
                for _ in range(trials):
                    time.sleep(0.3)  # PAIN and ROTATE back at rest
                    brick.set(distance_cm=3.0)
                    start = brick.changed_at
                    while not any(c.turn and c.at > start for c in brick.commands):
                        time.sleep(0.0005)
                        if time.monotonic() - start > wait_s:
                            raise SystemExit(f"no spin within {wait_s:g} s of the obstacle")
                    spin = next(c for c in brick.commands if c.turn and c.at > start)
                    latencies.append((spin.at - start) * 1000)
                    brick.set(distance_cm=100.0)
            finally:
                brain.send_signal(signal.SIGTERM)
                brain.wait(30)
                gateway.send_signal(signal.SIGTERM)
                gateway.wait(30)
        return latencies, json.loads((Path(tmp) / "b.json").read_text())


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench gateway", description=(__doc__ or "").partition("\n")[0])
    p.add_argument("--seconds", type=positive, default=5.0, help="for the polls/s figure (default 5)")
    p.add_argument("--trials", type=at_least(1), default=40, help="obstacles put before the robot (default 40)")
    p.add_argument("--clock", type=positive, default=1000.0, help="the brain's clock in Hz (default 1000)")
    args = p.parse_args(argv)
    polls = polls_per_s(args.seconds)
    print(f"gateway polling the fake brick: {polls:,.0f} polls/s (3 sensors per poll, one direct command)")
    latencies, brain = chain(args.trials, args.clock)
    lat = np.array(latencies)
    print(
        f"sensor -> motor, {len(lat)} trials: median {np.median(lat):.2f} ms, p90 {np.percentile(lat, 90):.2f} ms "
        f"(of which the circuit: PAIN -> ROTATE, a delay of 3 ticks at {args.clock:g} Hz)"
    )
    print(
        f"free-running brain: {brain['hz']:,.1f} Hz, lateness median {brain['late_ms_median']:.3f} ms, "
        f"p99 {brain['late_ms_p99']:.3f} ms, max {brain['late_ms_max']:.3f} ms"
    )
    result = {
        "polls_per_s": round(polls),
        "sensor_to_motor_ms_median": round(float(np.median(lat)), 2),
        "brain_hz": brain["hz"],
        "brain_jitter_ms_p99": brain["late_ms_p99"],
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
