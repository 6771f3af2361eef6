"""What `spikinglab run` listens on, read from the system while it runs (every process of the run:
the launcher and its children): Unix sockets in the run's private folder and nothing else; with
--view, also the live view's servers, on 127.0.0.1 only."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from .processes import ROOT, running_with
from .sockets import Listener, listeners

SERVICES = ("services.world", "services.brain", "services.recorder")  # the modules of the run's services
SETTLE_S = 3.0  # after every service listens: long enough for a listener opened later to show


def run_listeners(tmp_path: Path, *options: str, tcp: int = 0, env=None) -> tuple[list[Listener], str]:
    """Every listener of a run with `options`, seen while it runs: sampled until each service
    listens, `tcp` TCP listeners are up and the brain has answered the world, then for SETTLE_S
    more; then the run is ended with Ctrl-C. Returns them and what the run said on stderr."""
    command = [
        sys.executable,
        "-m",
        "spikinglab",
        "run",
        "--ticks",
        "400000",
        "--quiet",
        "--runs",
        tmp_path,
        "--id",
        "r",
    ]
    run = subprocess.Popen(
        [*map(str, command), *options], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    seen: set[Listener] = set()
    try:
        deadline, settled_at = time.monotonic() + 120, None
        while settled_at is None or time.monotonic() < settled_at:
            assert run.poll() is None, f"the run ended: {run.communicate()[1]}"
            assert time.monotonic() < deadline, f"not every service listened: {sorted(seen, key=str)}"
            seen.update(listeners(run.pid))
            everyone = all(any(service in s.name for s in seen) for service in SERVICES)
            brain = tmp_path / "r" / "brain.log"
            answered = brain.exists() and "brain for" in brain.read_text()
            if settled_at is None and everyone and answered and sum(s.kind == "tcp" for s in seen) >= tcp:
                settled_at = time.monotonic() + SETTLE_S
            time.sleep(0.2)
    finally:
        run.send_signal(signal.SIGINT)
        said = run.communicate(timeout=120)[1]
    assert run.returncode == 130, said
    assert not running_with(str(tmp_path))
    return sorted(seen, key=str), said


def private_folder(found: list[Listener]) -> Path:
    """The one folder that holds every Unix socket of the run: the launcher's, in the temporary
    folder, gone after the run."""
    folders = {Path(s.address).parent for s in found if s.kind == "unix"}
    assert len(folders) == 1, f"Unix sockets in more than one folder: {found}"
    (folder,) = folders
    assert folder.parent == Path(tempfile.gettempdir()) and folder.name.startswith("spikinglab-"), folder
    assert not folder.exists()  # removed with the run
    return folder


def test_run_listens_on_unix_sockets_in_its_private_folder_only(tmp_path):
    found, _ = run_listeners(tmp_path)
    elsewhere = [s for s in found if s.kind != "unix"]
    assert not elsewhere, f"the run listens on a network interface: {elsewhere}"
    private_folder(found)


def test_run_view_serves_the_live_view_on_the_loopback_only(tmp_path):
    """Without a display: the recorder's gRPC server and the web viewer's page, on 127.0.0.1."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    found, said = run_listeners(tmp_path, "--view", tcp=2, env=env)
    private_folder(found)
    network = [s for s in found if s.kind != "unix"]
    assert all(s.kind == "tcp" and s.address.startswith("127.0.0.1:") for s in network), network
    page = said.split("open ", 1)[1].split()[0]  # the address printed is one of them
    assert page.startswith("http://127.0.0.1:") and any(page.startswith(f"http://{s.address}/") for s in network)


def test_view_host_is_an_option_of_the_live_view():
    from services.run import arguments, parser

    with pytest.raises(SystemExit) as stopped:
        arguments(parser(), ["--view-host", "0.0.0.0"])
    assert stopped.value.code == 2
    with pytest.raises(SystemExit) as stopped:
        arguments(parser(), ["--view", "--view-host", "my-laptop"])
    assert stopped.value.code == 2
    assert arguments(parser(), ["--view", "--view-host", "0.0.0.0"]).view_host == "0.0.0.0"
