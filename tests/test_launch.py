"""`spikinglab launch` on the shipped launch files: real services on real ports, run from a temp folder."""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest

import services.launch
from services.launch import Child, Launcher, Process, local_endpoints, shipped
from spikinglab import cli

from .launching import READY, launch, launch_file
from .processes import free_port, running_with, wait_for


def test_simulation_runs_world_brain_and_recorder_with_prefixed_logs(tmp_path):
    run = launch(tmp_path, launch_file("simulation", tmp_path, **{"ticks = 20000": "ticks = 3000"}))
    out, err = run.communicate(timeout=180)
    assert run.returncode == 0, out + err
    for name in ("world", "brain", "recorder"):
        assert any(line.strip().startswith(f"{name} |") for line in out.splitlines()), out
    assert "weights saved" in out and "recording written" in out and "(ticks 0..2999)" in out  # the last tick's number
    result = tmp_path / "runs" / "launch-simulation"
    assert json.loads((result / "metrics.json").read_text())["ticks"] == 3000
    assert (result / "weights.npz").stat().st_size > 0 and (result / "recording.rrd").stat().st_size > 0
    assert not running_with(str(tmp_path))


def test_robot_runs_the_gateway_on_a_fake_brick_and_ends_with_the_gateway(tmp_path):
    run = launch(tmp_path, launch_file("robot", tmp_path, **{"duration = 60": "duration = 5"}))
    out, err = run.communicate(timeout=120)
    assert run.returncode == 0, out + err
    stats = json.loads((tmp_path / "runs" / "launch-robot" / "gateway.json").read_text())
    assert stats["polls"] > 100 and stats["commands"] > 0  # sensors read, the brain's MOVEs sent to the brick
    assert (tmp_path / "runs" / "launch-robot" / "weights.npz").exists()  # the gateway's end reached the brain
    assert not running_with(str(tmp_path))


def test_remote_brain_joins_the_world_through_the_router(tmp_path):
    port = free_port()
    world_side = launch(
        tmp_path, launch_file("remote-world", tmp_path, **{"7447": port, "ticks = 20000": "ticks = 3000"})
    )
    brain_side = launch(tmp_path, launch_file("remote-brain", tmp_path, **{"7447": port}))
    out, err = world_side.communicate(timeout=180)
    assert world_side.returncode == 0, out + err
    brain_out, brain_err = brain_side.communicate(timeout=60)
    assert brain_side.returncode == 0, brain_out + brain_err
    assert "weights saved" in brain_out
    assert json.loads((tmp_path / "runs" / "launch-remote" / "metrics.json").read_text())["ticks"] == 3000
    assert not running_with(str(tmp_path))


def test_sharded_simulation_runs_three_brain_shards_each_with_its_slice(tmp_path):
    run = launch(
        tmp_path,
        launch_file(
            "sharded-simulation", tmp_path, **{"ticks = 20000": "ticks = 2000", "agents = 3000": "agents = 30"}
        ),
    )
    out, err = run.communicate(timeout=180)
    assert run.returncode == 0, out + err
    result = tmp_path / "runs" / "launch-sharded"
    assert json.loads((result / "metrics.json").read_text())["agents"] == 30
    for i in (1, 2, 3):
        assert any(
            line.strip().startswith(f"brain-{i} |") and f"shard {i} of 3" in line for line in out.splitlines()
        ), out
        with np.load(result / f"weights-{i}of3.npz") as saved:
            assert saved["weights"].shape[0] == 10
    assert not running_with(str(tmp_path))


def test_secure_launch_files_run_over_mutual_tls_once_certs_are_made(tmp_path):
    files = [
        launch_file("secure-simulation", tmp_path, **{"ticks = 20000": "ticks = 2000"}),
        launch_file("secure-robot", tmp_path, **{"duration = 60": "duration = 4"}),
    ]
    refused = launch(tmp_path, files[0])  # before `spikinglab certs`: refused, and told what to do
    out, err = refused.communicate(timeout=60)
    assert refused.returncode == 2 and "cannot read certs/router.json5" in err and "spikinglab certs" in err, err
    made = subprocess.run(
        [sys.executable, "-m", "spikinglab", "certs", "certs"], cwd=tmp_path, capture_output=True, text=True
    )
    assert made.returncode == 0, made.stderr
    for file in files:
        run = launch(tmp_path, file)
        out, err = run.communicate(timeout=180)
        assert run.returncode == 0, out + err
        assert "rejected: none" in out
    assert json.loads((tmp_path / "runs" / "launch-secure" / "metrics.json").read_text())["ticks"] == 2000
    stats = json.loads((tmp_path / "runs" / "launch-secure-robot" / "gateway.json").read_text())
    assert stats["commands"] > 0  # the brain's MOVEs passed the router's rules to the gateway
    assert not running_with(str(tmp_path))


def test_a_service_that_dies_ends_the_launch_and_is_named(tmp_path):
    file, config = tmp_path / "broken.toml", tmp_path / "boss.json5"
    config.write_text('{mode: "boss"}\n')  # JSON5 that the launch's check reads; Zenoh refuses it as the brain starts
    file.write_text(
        f'[launch]\nuntil = "world"\n[world]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
        f'ticks = 1000000\n[brain]\nzenoh_config = "{config}"\n'
    )
    started = time.monotonic()
    run = launch(tmp_path, file)
    out, err = run.communicate(timeout=60)
    assert run.returncode == 1
    assert "the brain stopped (exit 1) before the world ended" in err, err
    assert "boss.json5" in err  # its last lines say why
    assert time.monotonic() - started < 30
    assert not running_with(str(tmp_path))


def test_a_service_ends_when_what_started_it_is_killed(tmp_path):
    """kill -9 of a launcher (or of a run, or a test) leaves no service running on without it."""
    (router_ep,), folder = local_endpoints("router")
    starter = subprocess.Popen(
        [sys.executable, "-c", STARTER, router_ep, str(tmp_path / "router.log")], stdout=subprocess.PIPE, text=True
    )
    started = [psutil.Process(starter.pid)]
    try:
        assert starter.stdout is not None  # stdout=PIPE
        started.append(router := psutil.Process(int(starter.stdout.readline())))
        wait_for(lambda: "router" in (tmp_path / "router.log").read_text(), 60, "the router to start")
        starter.kill()
        starter.wait()
        router.wait(timeout=10)  # raises psutil.TimeoutExpired while it runs on
    finally:
        for process in started:
            with contextlib.suppress(psutil.NoSuchProcess):
                process.kill()
        folder.cleanup()


STARTER = """import sys, time
from pathlib import Path
from services.launch import spawn
print(spawn("router", ["--listen", sys.argv[1]], Path(sys.argv[2])).pid, flush=True)
time.sleep(600)
"""


def test_every_shipped_launch_file_is_listed_here():
    assert set(READY) == set(shipped())


def test_finish_stops_what_did_not_end_in_time_and_then_the_endless_services(tmp_path):
    """A gateway with no --duration does not end by itself; a router and a fake brick never do."""
    (router_ep,), folder = local_endpoints("router")
    launcher = Launcher(colour=False)
    launcher.start(Process("router", "router", {"listen": [router_ep]}, log=tmp_path / "router.log"))
    launcher.start(Process("brick", "fake-brick", log=tmp_path / "brick.log"))
    launcher.start(Process("gateway", "gateway", {"connect": [router_ep]}, log=tmp_path / "gateway.log"))
    try:
        wait_for(lambda: "first reading published" in (tmp_path / "gateway.log").read_text(), 60, "the gateway")
        launcher.finish(timeout=1)
        ended = {name: child.popen.poll() for name, child in launcher.children.items()}
    finally:
        launcher.stop_all()
        folder.cleanup()
    assert ended == {"router": 0, "brick": 0, "gateway": 0}, ended  # each stopped the clean way (SIGTERM)


def test_a_service_that_does_not_end_on_its_sigterm_is_killed_and_named(caplog):
    ignoring = (
        "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('ready', flush=True); time.sleep(60)"
    )
    stubborn = subprocess.Popen([sys.executable, "-c", ignoring], stdout=subprocess.PIPE, text=True)
    try:
        assert stubborn.stdout is not None and stubborn.stdout.readline() == "ready\n"
        launcher = Launcher(colour=False)
        launcher.children["stubborn"] = Child(Process("stubborn", "stubborn"), stubborn, None, None)
        with caplog.at_level(logging.WARNING, logger="spikinglab.launch"):
            launcher.stop("stubborn", timeout=1)
    finally:
        stubborn.kill()
    assert stubborn.returncode == -signal.SIGKILL
    assert caplog.messages == ["the stubborn did not end within 1 s of its SIGTERM; killed it"]


def test_the_processes_of_one_service_are_sent_their_sigterm_together(tmp_path, caplog):
    """Three brain shards compiling at a Ctrl-C (which they take once the kernel is ready) are each
    given the stop's time at once, not in turn (three times as long), and each one killed is named."""
    noting = (
        "import pathlib, signal, sys, time\n"
        "signal.signal(signal.SIGTERM, lambda *_: pathlib.Path(sys.argv[1]).write_text(str(time.time())))\n"
        "print('ready', flush=True)\n"
        "time.sleep(60)"
    )
    launcher, notes = Launcher(colour=False), [tmp_path / f"{k}" for k in range(3)]
    stubborn = [
        subprocess.Popen([sys.executable, "-c", noting, note], stdout=subprocess.PIPE, text=True) for note in notes
    ]
    try:
        for k, popen in enumerate(stubborn):
            assert popen.stdout is not None and popen.stdout.readline() == "ready\n"
            launcher.children[f"brain-{k + 1}"] = Child(Process(f"brain-{k + 1}", "brain"), popen, None, None)
        with caplog.at_level(logging.WARNING, logger="spikinglab.launch"):
            launcher.stop_in_order(launcher.ending_order(), timeout=2)
    finally:
        for popen in stubborn:
            popen.kill()
    sigterm_at = [float(note.read_text()) for note in notes]
    assert max(sigterm_at) - min(sigterm_at) < 1  # in turn: 2 s apart
    assert caplog.messages == [f"the brain-{k} did not end within 2 s of its SIGTERM; killed it" for k in (1, 2, 3)]


def test_ctrl_c_while_the_launch_file_is_read_is_one_line(monkeypatch, capsys):
    """Ctrl-C as launch reads its file (importing each service's options takes about a second),
    before any process started: one line and exit 130, not a traceback."""

    def interrupted(path):
        raise KeyboardInterrupt

    monkeypatch.setattr(services.launch, "read_launch_file", interrupted)
    with pytest.raises(SystemExit) as ended:
        cli.main(["launch", "simulation"])
    assert ended.value.code == 130
    assert capsys.readouterr().err == "spikinglab launch: interrupted\n"
