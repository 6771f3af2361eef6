"""`spikinglab launch` on the shipped launch files: real services on real ports, run from a temp folder."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np

from services.launch import shipped

from .processes import free_port, running_with, wait_for


def launch_file(name: str, folder, **replace) -> str:
    """A shipped launch file with its ports moved to free ones (and any other text replaced)."""
    text = shipped()[name].read_text()
    for port in ("7447", "7448"):
        text = text.replace(port, str(replace.pop(port, free_port())))
    for old, new in replace.items():
        text = text.replace(old, new)
    path = folder / f"{name}.toml"
    path.write_text(text)
    return str(path)


def launch(folder, *args, stdout=subprocess.PIPE) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "spikinglab", "launch", *map(str, args), "--no-colour"],
        cwd=folder,
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_simulation_runs_world_brain_and_recorder_with_prefixed_logs(tmp_path):
    run = launch(tmp_path, launch_file("simulation", tmp_path, **{"ticks = 20000": "ticks = 3000"}))
    out, err = run.communicate(timeout=180)
    assert run.returncode == 0, out + err
    for name in ("world", "brain", "recorder"):
        assert any(line.strip().startswith(f"{name} |") for line in out.splitlines()), out
    assert "weights saved" in out and "recording written" in out
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
    file = tmp_path / "broken.toml"
    file.write_text(
        f'[launch]\nuntil = "world"\n[world]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
        f'ticks = 1000000\n[brain]\ncircuit = "{tmp_path}/missing.toml"\n'
    )
    started = time.monotonic()
    run = launch(tmp_path, file)
    out, err = run.communicate(timeout=60)
    assert run.returncode == 1
    assert "the brain stopped (exit 2) before the world ended" in err, err
    assert "missing.toml" in err  # its last lines say why
    assert time.monotonic() - started < 30
    assert not running_with(str(tmp_path))


def test_ctrl_c_ends_every_service_and_the_world_writes_its_ticks(tmp_path):
    log = tmp_path / "launch.log"
    with open(log, "w") as out:
        run = launch(tmp_path, launch_file("simulation", tmp_path, **{"ticks = 20000": "ticks = 5000000"}), stdout=out)
        wait_for(lambda: "tick/s" in log.read_text(), 120, "the world's progress")  # ticking
        run.send_signal(signal.SIGINT)
        _, err = run.communicate(timeout=90)
    assert run.returncode == 130, log.read_text() + err
    metrics = json.loads((tmp_path / "runs" / "launch-simulation" / "metrics.json").read_text())
    assert metrics["partial"] is True and metrics["ticks"] > 0
    assert not running_with(str(tmp_path))
