"""Real service processes on loopback for integration tests, and a session that watches the bus."""

from __future__ import annotations

import os
import socket
import subprocess
import time
from pathlib import Path

import zenoh

from services.bus.config import make_config
from services.bus.schemas import BusError, decode
from services.launch import spawn

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def start(service: str, *args, log: Path | None = None) -> subprocess.Popen:
    """A service (launch.SERVICES: world, brain, record, gateway, ...) with `args`, its output into
    `log` (read it when a test fails)."""
    return spawn(service, list(args), log or subprocess.DEVNULL, cwd=ROOT)


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


def wait_for(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.02)


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
