"""The gateway installed alone, as on the small computer next to the robot (docs/robot.md): a fresh
venv with services/ev3_gateway/requirements.txt and the project without its dependencies, where
numba, rerun, matplotlib and pymunk cannot be imported; from that venv the fake brick and the
gateway (ev3 backend, WiFi) run on loopback, watched and driven from this test's own session."""

import json
import os
import re
import shutil
import signal
import subprocess
import time
import tomllib
import venv
from pathlib import Path

import numpy as np
import pytest

from services.bus import keys
from services.bus.schemas import Array, Motor, encode
from services.vocabulary import INSECT_ACTIONS, INSECT_SENSORS

from ..processes import ROOT, Watcher, endpoint, finish, wait_for

REQUIREMENTS = ROOT / "services" / "ev3_gateway" / "requirements.txt"
HEAVY = ("numba", "rerun", "matplotlib", "pymunk")
GROUP = keys.DEFAULT_GROUP


def required() -> list[str]:
    return [line.strip() for line in REQUIREMENTS.read_text().splitlines() if line.strip() and line[0] != "#"]


def test_the_gateways_requirements_are_pyprojects_own_lines():
    """Each line as pyproject.toml states it (the base dependencies or the ev3 extra), so the two
    cannot drift apart, and none of the packages the gateway does without."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    stated = {*project["dependencies"], *project["optional-dependencies"]["ev3"]}
    lines = required()
    assert lines and set(lines) <= stated, set(lines) - stated
    names = {re.split(r"[<>=!~\[ ]", line)[0] for line in lines}
    assert not names & {"numba", "rerun-sdk", "matplotlib", "pymunk"}


def gateway_only_venv(folder: Path) -> Path:
    """A venv with the requirements and the project (a copy of its packages) without dependencies:
    its bin/ folder."""
    source = folder / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    for package in ("spikinglab", "services"):
        shutil.copytree(ROOT / package, source / package, ignore=shutil.ignore_patterns("__pycache__"))
    venv.create(folder / "venv", with_pip=True)
    bin_dir = folder / "venv" / "bin"
    for args in (["-r", REQUIREMENTS], ["--no-deps", source]):
        done = subprocess.run([bin_dir / "pip", "install", "-q", *args], capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr
    return bin_dir


def act_as_brain(watcher: Watcher, readings: list):
    """A brain's liveliness token (kept while the caller holds it), then ROTATE answering the latest
    reading."""
    token = watcher.session.liveliness().declare_token(keys.alive(GROUP, "brain"))
    time.sleep(0.3)  # the gateway sees the token before the command
    latest = readings[-1]
    rotate = Motor(
        tick=1,
        names=INSECT_ACTIONS,
        actions=Array.of(np.array([[1, 0]], np.uint8)),
        run=latest.run,
        reading=latest.tick,
    )
    watcher.session.put(keys.motor(GROUP), encode(rotate))
    return token


@pytest.mark.timeout(1800)  # a fresh machine downloads the dependencies (pip's own limit is 900 s)
def test_the_gateway_alone(tmp_path):
    bin_dir = gateway_only_venv(tmp_path)
    elsewhere = tmp_path / "elsewhere"  # no checkout on the path: the venv's copy runs
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}

    def in_venv(*args, **kwargs) -> subprocess.CompletedProcess:
        return subprocess.run([*map(str, args)], cwd=elsewhere, env=env, capture_output=True, text=True, **kwargs)

    for module in HEAVY:
        assert in_venv(bin_dir / "python", "-c", f"import {module}").returncode == 1, f"{module} is installed"
    sim = in_venv(bin_dir / "spikinglab", "gateway", "--backend", "sim", timeout=60)
    assert sim.returncode == 2 and sim.stderr.count("\n") == 1, sim.stderr
    assert "--backend sim needs the simulated world" in sim.stderr
    run = in_venv(bin_dir / "spikinglab", "run", "--ticks", "1000", timeout=60)  # a command this install leaves out
    assert (run.returncode, run.stderr.count("\n")) == (2, 1), run.stderr
    assert run.stderr.startswith("spikinglab run: needs the package "), run.stderr

    gateway_ep = endpoint(tmp_path, "gateway")
    brick_log, gateway_log = tmp_path / "brick.log", tmp_path / "gateway.log"
    with brick_log.open("w") as b, gateway_log.open("w") as g:
        brick = subprocess.Popen(
            [bin_dir / "python", "-m", "spikinglab", "fake-brick", "--report-every", "0.2"],
            cwd=elsewhere,
            env=env,
            stdout=b,
            stderr=subprocess.STDOUT,
        )
        gateway = subprocess.Popen(
            [bin_dir / "spikinglab", "gateway", "--listen", gateway_ep, "--max-polls", "1000"]
            + ["--stats", tmp_path / "gateway.json"],
            cwd=elsewhere,
            env=env,
            stdout=g,
            stderr=subprocess.STDOUT,
        )
    watcher = Watcher([gateway_ep], [keys.sensors(GROUP)])
    readings = watcher.messages[keys.sensors(GROUP)]
    try:
        wait_for(lambda: len(readings) > 100, 60, "readings on the bus")
        assert all(r.names == INSECT_SENSORS and r.values.shape == (1, len(INSECT_SENSORS)) for r in readings)
        assert not watcher.bad
        brain = act_as_brain(watcher, readings)
        wait_for(lambda: "a brain drives the robot" in gateway_log.read_text(), 10, "the gateway to follow the brain")
        wait_for(lambda: re.search(r"motor commands [1-9]", brick_log.read_text()), 10, "the spin on the brick")
        gateway.send_signal(signal.SIGINT)  # Ctrl-C
        assert finish(gateway, 30, gateway_log) == 0
        brick.send_signal(signal.SIGINT)
        assert finish(brick, 30, brick_log) == 0
        brain.undeclare()
    finally:
        watcher.close()
        gateway.kill()
        brick.kill()
    log = gateway_log.read_text()
    assert "robot linked" in log and "gateway done" in log and "Traceback" not in log
    stats = json.loads((tmp_path / "gateway.json").read_text())
    assert stats["polls"] > 100 and stats["commands"] == 1 and stats["link_losses"] == 0
    assert (
        str(tmp_path / "venv") in in_venv(bin_dir / "python", "-c", "import services; print(services.__file__)").stdout
    )
