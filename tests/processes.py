"""Real service processes on loopback for integration tests, and a session that watches the bus."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import zenoh

from services.bus import keys
from services.bus.config import make_config
from services.bus.schemas import BusError, decode
from services.launch import spawn
from spikinglab.bench.gateway import gateway_and_brain as robot_chain

from .sockets import listeners

ROOT = Path(__file__).resolve().parents[1]


SOCKET_PATH_MAX = 107  # bytes in a Unix socket's path (sun_path is 108 with its terminating NUL)


def endpoint(folder: Path | int, name: str = "") -> str:
    """An endpoint for a service to listen on: a Unix socket `name`.sock in `folder` (the test's
    tmp_path), which no other process can take between the test choosing it and the service binding
    it, as a TCP port handed over by number can be. An int is such a port: `tcp/127.0.0.1:<port>`,
    for the callers not yet moved to sockets."""
    if isinstance(folder, int):
        return f"tcp/127.0.0.1:{folder}"
    path = Path(folder) / f"{name}.sock"
    if len(str(path).encode()) > SOCKET_PATH_MAX:
        raise ValueError(f"{path}: longer than a Unix socket's path may be ({SOCKET_PATH_MAX} bytes)")
    return f"unixsock-stream/{path}"


def free_port() -> int:
    """A TCP port free now, which another process may take before the caller's service binds it:
    prefer endpoint(tmp_path, name), or a service listening on port 0 and bound_port()."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bound_port(process: subprocess.Popen, timeout: float = 30) -> int:
    """The TCP port that `process` (or a process it started) listens on, once it does: for a service
    told to listen on port 0, which then binds a free one itself."""
    found: list[int] = []

    def listening() -> bool:
        assert process.poll() is None, f"{process.args} ended with {process.returncode} before it listened"
        found[:] = [int(s.address.rpartition(":")[2]) for s in listeners(process.pid) if s.kind == "tcp"]
        return bool(found)

    wait_for(listening, timeout, f"{process.args} to listen on a TCP port")
    assert len(set(found)) == 1, f"{process.args} listens on several TCP ports: {found}"
    return found[0]


def start(service: str, *args, log: Path | None = None) -> subprocess.Popen:
    """A service (launch.SERVICES: world, brain, record, gateway, ...) with `args`, its output into
    `log` (read it when a test fails)."""
    return spawn(service, list(args), log or subprocess.DEVNULL, cwd=ROOT)


def gateway_and_brain(folder: Path, gateway=(), brain=()) -> tuple[subprocess.Popen, subprocess.Popen]:
    """The gateway (by default its ev3 backend: the fake brick) and a free-running brain at 1,000 Hz
    driving it, with their further options, listening on gateway.sock and brain.sock in `folder`
    and logging into gateway.log and brain.log there."""
    return robot_chain(endpoint(folder, "gateway"), endpoint(folder, "brain"), 1000, gateway, brain, folder, ROOT)


def wait_for_driving(folder: Path) -> None:
    """Until gateway_and_brain's gateway follows the brain: the brain compiles its kernels before it
    joins the bus, a minute and more on a cold kernel cache and a busy machine."""
    log = folder / "gateway.log"
    wait_for(lambda: "a brain drives the robot" in log.read_text(), 180, "the brain to drive the robot")


def world_and_brain(folder: Path, world=(), brain=()) -> tuple[subprocess.Popen, subprocess.Popen]:
    """A world and a brain that serves its one run, lock-step, both publishing their state, with
    their further options, listening on world.sock and brain.sock in `folder` and logging into
    world.log and brain.log there."""
    world_ep, brain_ep = endpoint(folder, "world"), endpoint(folder, "brain")
    brain_args = ["--listen", brain_ep, "--connect", world_ep, "--once", "--publish-state", *brain]
    return (
        start("world", "--listen", world_ep, "--publish-state", *world, log=folder / "world.log"),
        start("brain", *brain_args, log=folder / "brain.log"),
    )


def connecting(*endpoints: str) -> list[str]:
    """A service's options to connect to each of `endpoints`."""
    return [word for e in endpoints for word in ("--connect", e)]


def finish(process: subprocess.Popen, timeout: float, log: Path | None = None) -> int:
    try:
        return process.wait(timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        detail = log.read_text()[-3000:] if log and log.exists() else ""
        raise AssertionError(f"{process.args} did not finish in {timeout} s\n{detail}") from None


class Watcher:
    """A session connected to the given endpoints that keeps every decoded message of some keys."""

    def __init__(self, connect: list[str], keys: list[str]):
        self.session = zenoh.open(make_config(connect=connect))
        self.messages: dict[str, list] = {k: [] for k in keys}
        self.bad: list[str] = []
        self._subs = [self.session.declare_subscriber(k, self._keep(k)) for k in keys]

    def _keep(self, key):
        def on_sample(sample):
            try:
                self.messages[key].append(decode(sample.payload.to_bytes()))
            except BusError as e:
                self.bad.append(str(e))

        return on_sample

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()


def ticks_in(states: list) -> list[int]:
    """The ticks covered by a list of WorldState (or BrainState) batches."""
    return [m.tick + k for m in states for k in range((m.pos if hasattr(m, "pos") else m.spiked).shape[0])]


def logged(text: str, pattern: str) -> re.Match:
    """Where `pattern` is in a log's text; an assertion showing the log's end when it is not."""
    found = re.search(pattern, text)
    assert found, f"no {pattern!r} in the log:\n{text[-2000:]}"
    return found


def wait_for(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.02)


def watched_world(folder: Path, group: str, *options) -> tuple[subprocess.Popen, Watcher, list]:
    """A world of `group` with `options`, publishing its state, listening on world.sock in `folder`
    and logging into world.log there; a Watcher of it that the caller closes, connected first (it
    sees every tick); and the list its WorldState messages come into."""
    world_ep = endpoint(folder, "world")
    watcher = Watcher([world_ep], [keys.world_state(group)])
    world = start(
        "world", "--group", group, "--listen", world_ep, "--publish-state", *options, log=folder / "world.log"
    )
    return world, watcher, watcher.messages[keys.world_state(group)]


def kill_mid_run(victim: subprocess.Popen, states: list, world_log: Path, who: str) -> None:
    """kill -9 of `victim` (a brain, a brain shard) once the run has passed tick 1000 (`states`: the
    world's WorldState messages as they come): the world's log says `who` is lost within 10 s, and
    no tick comes for 1.5 s after."""
    wait_for(lambda: len(ticks_in(states)) > 1000, 60, "the run to pass tick 1000")
    victim.kill()
    victim.wait()
    wait_for(lambda: f"{who} lost at tick" in world_log.read_text(), 10, f"the world to say the {who} is lost")
    stalled_at = len(ticks_in(states))
    time.sleep(1.5)
    assert len(ticks_in(states)) == stalled_at  # the world waits: no tick without every brain


def continued_where_lost(world_log: Path, who: str, states: list, ticks: int) -> None:
    """After kill_mid_run and a new `who`: the world's log says at which tick it lost `who` and that it
    continued there, and the run published every one of its `ticks` once, none skipped."""
    log = world_log.read_text()
    lost = int(logged(log, rf"{re.escape(who)} lost at tick (\d+)").group(1))
    assert 1000 <= lost < ticks and f"{who} back: continuing at tick {lost}" in log
    assert ticks_in(states) == list(range(ticks))


def wait_for_ticks(folder: Path, timeout: float = 60) -> None:
    """Until the run in `folder` is under way: its brain has answered (it logs its first sensors)."""
    log = folder / "brain.log"
    wait_for(lambda: log.exists() and " brain for " in log.read_text(), timeout, "the run to start")
    time.sleep(2)


def live_run(runs: Path, run_id: str, env: dict) -> tuple[subprocess.Popen, str]:
    """`spikinglab run --view` into runs/run_id, and what it said on stderr up to its live view's line."""
    run = subprocess.Popen(
        [sys.executable, "-m", "spikinglab", "run", "--view", "--ticks", "400000", "--quiet"]
        + ["--runs", str(runs), "--id", run_id],
        cwd=ROOT,
        env=env,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    assert run.stderr is not None  # stderr=PIPE
    said = ""
    while "live view" not in said:
        line = run.stderr.readline()
        if not line:
            run.kill()
            raise AssertionError(f"the run ended without a live view:\n{said}")
        said += line
    return run, said


def running_with(marker: str) -> dict[int, str]:
    """The processes still running that name `marker` (a test's folder): pid -> command line."""
    found = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmdline = f.read().replace(b"\0", b" ").decode(errors="replace")
            with open(f"/proc/{pid}/stat") as f:
                zombie = f.read().rsplit(")", 1)[1].split()[0] == "Z"
        except OSError:
            continue
        if marker in cmdline and int(pid) != os.getpid() and not zombie:
            found[int(pid)] = cmdline
    return found
