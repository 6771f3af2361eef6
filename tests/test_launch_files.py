"""Each shipped launch file run once: what it listens on, read from the system while it runs (every
process: the launcher and its children), against the table in docs/launch.md (nothing more, and
nothing beyond the loopback that the table does not say); then Ctrl-C ends every service at once."""

from __future__ import annotations

import contextlib
import json
import re
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import psutil
import pytest

from services.commands import SERVICES
from services.launch import Process, shipped

from .launching import READY, launch, launch_file
from .processes import ROOT, free_port, running_with
from .sockets import Listener, listeners, process_tree

TABLE_HEADING = "## What each file listens on"
SETTLE_S = 3.0  # after every service is at work: long enough for a listener opened later to show
LOOPBACK = "127.0.0.1"
CTRL_C_S = 10  # every launch ends within 3 s of Ctrl-C; this bound leaves room for a loaded
# machine and still catches a service that the launcher has to kill after its 30 s
BEYOND_LOOPBACK = {  # the only processes that listen on a network interface: the router the brain's
    # machine dials, ev3-dc's search for the EV3's WiFi beacon (a broadcast), and the socket the fake
    # brick sends its beacon from (bound by the system to every interface; it reads nothing there)
    "remote-world": {"router"},
    "robot": {"gateway", "brick"},
    "secure-robot": {"gateway", "brick"},
}


def documented() -> dict[str, dict[str, list[str]]]:
    """docs/launch.md's table: file -> process -> the endpoints it listens on, as written there
    (`nothing`: none). A row may name several processes of a file, separated by commas."""
    text = (ROOT / "docs" / "launch.md").read_text()
    section = text.split(TABLE_HEADING, 1)[1].split("\n## ", 1)[0]
    table: dict[str, dict[str, list[str]]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not cells[0].startswith("`"):
            continue
        file, processes, listens = cells[0].strip("`"), cells[1], cells[2]
        endpoints = re.findall(r"`((?:tcp|tls|udp)/[^`]+)`", listens)
        assert endpoints or listens.startswith("nothing"), line
        for process in processes.split(", "):
            table.setdefault(file, {})[process] = endpoints
    return table


def allows(endpoint: str, seen: Listener, ports: dict[str, int]) -> bool:
    """Whether `seen` is `endpoint` of the table: the same kind (tls is TCP) and host, and the same
    port (a shipped port as the test moved it; 0: any; "the next free port up": that one or above)."""
    protocol, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    kind = "udp" if protocol == "udp" else "tcp"
    seen_host, _, seen_port = seen.address.rpartition(":")
    wanted = ports.get(port, int(port))
    return (
        seen.kind == kind
        and seen_host == host
        and (wanted == 0 or int(seen_port) == wanted or wanted == 5555 and int(seen_port) > wanted)
    )


def processes_of(file: Path) -> list[Process]:
    """A launch file's processes as the launcher starts them (unchecked: a secure file's checks
    read its certificates, which are relative to the folder launched from)."""
    tables = tomllib.loads(file.read_text())
    tables.pop("launch", None)
    return [Process(name, table.pop("service", name), table) for name, table in tables.items()]


def process_names(file: Path, launcher_pid: int) -> dict[int, str]:
    """The launch file's process name of each pid of the launch (the launcher: "launch"), matched by
    the command line the launcher gives it."""
    commands: dict[tuple[str, ...], str] = {(SERVICES[p.service], *p.argv()): p.name for p in processes_of(file)}
    launcher = psutil.Process(launcher_pid)
    names = {launcher_pid: "launch"}
    for child in launcher.children(recursive=True):
        try:
            cmdline = child.cmdline()
        except psutil.NoSuchProcess:
            continue
        if cmdline in (launcher.cmdline(), []):
            # forked by the launcher, not yet the service it becomes; or inside execve, where the new
            # program's arguments are not yet in place (read as none), or dead (a zombie)
            continue
        command = tuple(cmdline[2:])
        assert command in commands, f"a process that the launch file does not name: {cmdline}"
        names[child.pid] = commands[command]
    return names


@dataclass
class Launched:
    """What a launch file's run showed: its listeners by process name, the names of the processes
    seen, how long after Ctrl-C it ended and with what code, the services of it then and those
    still running after, and its log."""

    listeners: list[tuple[str, Listener]]
    running: set[str]
    ended_s: float
    returncode: int | None
    services: int
    left: list[list[str]]
    log: str


def launched(tmp_path: Path, name: str, ports: dict[str, int]) -> Launched:
    """`name` launched (ports moved as `ports` says), its listeners sampled from its start until
    its services are at work and SETTLE_S more; then Ctrl-C."""
    file = Path(launch_file(name, tmp_path, **{"ticks = 20000": "ticks = 5000000"}, **ports))
    log = tmp_path / "launch.log"
    seen: set[tuple[str, Listener]] = set()
    running: set[str] = set()
    services: list[psutil.Process] = []
    with open(log, "w") as out:
        run = launch(tmp_path, file, stdout=out)
        try:
            deadline, settled_at = time.monotonic() + 120, None
            while settled_at is None or time.monotonic() < settled_at:
                assert run.poll() is None, log.read_text() + run.communicate()[1]
                assert time.monotonic() < deadline, f"{name} not under way: {log.read_text()}"
                names = process_names(file, run.pid)
                running.update(names.values())
                seen.update((names.get(s.pid, "?"), s) for s in listeners(run.pid))
                if settled_at is None and all(re.search(line, log.read_text()) for line in READY[name]):
                    settled_at = time.monotonic() + SETTLE_S
                time.sleep(0.1)
            services = process_tree(run.pid)[1:]
            interrupted_at = time.monotonic()
            run.send_signal(signal.SIGINT)
            try:
                _, err = run.communicate(timeout=60)
            except subprocess.TimeoutExpired as e:
                raise AssertionError(f"{name} still ending 60 s after Ctrl-C: {e.stderr}\n{log.read_text()}") from None
            ended_s = time.monotonic() - interrupted_at
            left = [p.cmdline() for p in services if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
        finally:
            for process in [*process_tree(run.pid), *services]:  # on a failure too: nothing left running
                with contextlib.suppress(psutil.NoSuchProcess):
                    process.kill()
    return Launched(sorted(seen, key=str), running, ended_s, run.returncode, len(services), left, log.read_text() + err)


def test_the_table_names_every_process_of_every_shipped_file():
    table = documented()
    assert set(table) == set(READY)
    for name, path in shipped().items():
        assert set(table[name]) == {p.name for p in processes_of(path)}, name


@pytest.mark.parametrize("name", sorted(READY))
def test_a_launch_file_listens_only_where_docs_launch_md_says_and_ends_at_once_on_ctrl_c(tmp_path, name):
    if name.startswith("secure"):
        made = subprocess.run(
            [sys.executable, "-m", "spikinglab", "certs", "certs"], cwd=tmp_path, capture_output=True, text=True
        )
        assert made.returncode == 0, made.stderr
    ports = {"7447": free_port(), "7448": free_port()}
    run = launched(tmp_path, name, ports)
    table = documented()[name]
    assert run.running == {*table, "launch"}, run.running
    found = run.listeners
    undocumented = [(p, s) for p, s in found if not any(allows(e, s, ports) for e in table.get(p, []))]
    assert not undocumented, f"{name} listens on what docs/launch.md does not say: {undocumented}"
    for process, endpoints in table.items():  # and on each TCP endpoint it says (a UDP search may be over)
        for e in endpoints:
            if not e.startswith("udp/"):
                assert any(p == process and allows(e, s, ports) for p, s in found), (process, e, found)
    beyond = [(p, s) for p, s in found if s.kind != "unix" and not s.address.startswith(LOOPBACK + ":")]
    assert all(p in BEYOND_LOOPBACK.get(name, ()) for p, s in beyond), f"{name} listens beyond the loopback: {beyond}"
    # Ctrl-C: every service ends at once, none is left
    print(f"{name}: {run.services} services ended {run.ended_s:.2f} s after Ctrl-C")
    assert run.returncode == 130, run.log
    assert run.ended_s < CTRL_C_S, run.log
    assert run.services == len(table) and not run.left, run.left
    assert not running_with(str(tmp_path))
    if name == "simulation":
        metrics = json.loads((tmp_path / "runs" / "launch-simulation" / "metrics.json").read_text())
        assert metrics["partial"] is True and metrics["ticks"] > 0  # the world wrote the ticks it did
    if name == "sharded-worlds":  # every brain shard ended the run with the lead's end, whatever tick it was at
        folder, saved = tmp_path / "runs" / "launch-sharded-worlds", [f"weights-{j}of3.npz" for j in (1, 2, 3)]
        weights = sorted(p.name for p in folder.glob("weights*.npz"))
        assert weights == saved, weights  # none kept as learning of a run that stopped without its end
