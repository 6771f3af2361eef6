"""The fused closed loop on a CUDA device (services/gpu.py) against the CPU path, same seeds.

Without a GPU the device run goes through numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1, set in
a subprocess before numba.cuda is imported; it runs the kernel in Python, so populations and runs
are small). With a GPU the same comparison runs on it too. docs/gpu.md says what must agree bit
for bit and why the positions on a real device are compared to within 1e-9 patch.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.gpu import check_device, fused_loop_cuda
from services.loop import evaluate, fused_loop, population

ROOT = Path(__file__).resolve().parents[1]  # not tests.processes: a GPU machine may lack the bus packages

# Three settings of A+, each on the seeds given. On seed 1 the insects collide and learn within
# the run: 200 ticks from tick 0 (learning times, in three launches), 60 ticks across the first
# bin's end (bins), the phased semantics for 150 ticks; then more seeds for fewer ticks. On a
# device, also many seeds for many ticks.
PARAMS = {"a_plus": [0.01, 0.03, 0.05]}
LEARNED_AFTER = 50
# name: (semantics, seeds, start tick, ticks, ticks per launch)
RUNS = {
    "learning": ("netlogo", [1], 0, 200, 80),
    "bin": ("netlogo", [1], 970, 60, 1000),
    "phased": ("phased", [1], 0, 150, 1000),
    "seeds": ("netlogo", [2, 3, 4, 5], 0, 100, 1000),
}
DEVICE_RUNS = {"many": ("netlogo", range(192), 0, 6000, 1000), "many phased": ("phased", range(192), 0, 6000, 1000)}
WORLD = ("pos", "heading", "grid", "last_patch", "events", "eaten", "bin_collisions")
METRICS = ("collisions", "collisions_by_colour", "food", "distance", "last_collision", "last_noxious")
METRICS += ("learned_at", "resets")
ENGINE = ("clock", "v", "w", "counters", "last_spike", "hist", "ring", "spiked")


def run(semantics: str, seeds, start: int, ticks: int, stretch: int | None) -> dict[str, np.ndarray]:
    """Everything the run leaves in the world and brain; stretch None: the CPU path."""
    world, brain = population(PARAMS, seeds, learned_after=LEARNED_AFTER, semantics=semantics)
    world.tick = start  # as a run resumed there
    noxious = np.zeros((ticks, world.agents), np.uint8)  # the ticks on a noxious patch, which sweeps read
    if stretch is None:
        fused_loop(world, brain, ticks, noxious)
    else:

        def keep(k, rows):
            noxious[k : k + len(rows)] = rows

        fused_loop_cuda(world, brain, ticks, stretch, keep)
    out = {name: np.asarray(getattr(world, name)) for name in WORLD} | {"noxious": noxious}
    out |= {f"metrics.{name}": getattr(world.metrics, name) for name in METRICS}
    out |= {f"engine.{name}": getattr(brain.engine.state, name) for name in ENGINE}
    bins = np.array(world.metrics.bins, np.int64).reshape(-1, world.agents)
    return out | {"bins": bins, "tick": np.array(world.tick), "actions": brain.actions}


def runs(simulator: bool) -> dict[str, tuple]:
    return RUNS if simulator else RUNS | DEVICE_RUNS


def device_runs(path: str, simulator: bool) -> None:
    """In the subprocess: every run on the device (or the simulator), saved to `path`."""
    arrays = {}
    for name, case in runs(simulator).items():
        arrays |= {f"{name}/{k}": v for k, v in run(*case).items()}
    np.savez(path, **arrays)


def on_device(tmp_path, simulator: bool) -> dict[str, np.ndarray]:
    path = tmp_path / "device.npz"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    if simulator:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    code = f"from tests.test_gpu import device_runs; device_runs({str(path)!r}, {simulator})"
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, check=True, timeout=280)
    return dict(np.load(path))


def device_present() -> bool:
    probe = "from services.gpu import device_problem; print(device_problem() is None)"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True)
    return done.stdout.strip() == "True"


@pytest.mark.parametrize("simulator", [True, False], ids=["simulator", "device"])
def test_device_run_equals_cpu(tmp_path, simulator):
    if not simulator and not device_present():
        pytest.skip("no CUDA device here (the simulator case compares the same kernel)")
    device = on_device(tmp_path, simulator)
    cpu_runs = {
        name: run(sem, seeds, start, ticks, None) for name, (sem, seeds, start, ticks, _) in runs(simulator).items()
    }
    for name, cpu in cpu_runs.items():
        for key, expected in cpu.items():
            got = device[f"{name}/{key}"]
            if key == "pos" and not simulator:  # the device's sin and cos may differ in the last bit
                np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9, err_msg=f"{name}: {key}")
            else:
                np.testing.assert_array_equal(got, expected, err_msg=f"{name}: {key}")
    # the runs compared something: collisions, learning, weights moved, a bin closed
    learning, crossing = cpu_runs["learning"], cpu_runs["bin"]
    assert learning["metrics.collisions"].sum() > 0 and (learning["metrics.learned_at"] > 0).any()
    assert learning["noxious"].sum() >= learning["metrics.collisions"].sum() > 0  # a collision is a tick on one
    _, brain = population(PARAMS, [1], learned_after=LEARNED_AFTER)
    for name in ("learning", "phased"):
        assert not np.array_equal(cpu_runs[name]["engine.w"], brain.engine.state.w), name
    assert crossing["bins"].shape == (1, 3) and crossing["bins"].sum() + crossing["bin_collisions"].sum() > 0


def test_cuda_refused_without_a_device_in_one_line():
    if device_present():
        pytest.skip("a CUDA device is present here")
    code = (
        "from services.loop import evaluate\n"
        "try:\n    evaluate({'a_plus': [0.01]}, 10, [0], device='cuda')\n"
        "except RuntimeError as e:\n    print(e)"
    )
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    message = done.stdout.strip()
    assert message.startswith("device='cuda' refused: ") and "\n" not in message, message
    assert "NVIDIA GPU" in message and "CPU path" in message, message
    evaluate({"a_plus": [0.01]}, 10, [0])  # the CPU path is untouched


def test_bench_gpu_prints_its_figures_under_the_simulator_and_is_refused_without_a_device():
    command = [sys.executable, "-m", "spikinglab", "bench", "gpu", "--agents", "2", "--ticks", "5"]
    command += ["--warmup", "1", "--cpu-ticks", "5"]
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    done = subprocess.run(command, cwd=ROOT, env=env | {"NUMBA_ENABLE_CUDASIM": "1"}, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    figures = json.loads(done.stdout.splitlines()[-1])
    assert figures["simulator"] and figures["agents"] == 2 and figures["device"] > 0 and figures["cpu"] > 0
    if not device_present():
        done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
        assert done.returncode == 2 and done.stderr.startswith("spikinglab bench gpu: refused: ")
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_an_unknown_device_is_named():
    with pytest.raises(ValueError, match="device must be one of cuda, got 'tpu'"):
        check_device("tpu")


def device_env() -> dict[str, str]:
    """The environment of a device run: the GPU where there is one, else numba's simulator."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    return env if device_present() else env | {"NUMBA_ENABLE_CUDASIM": "1"}


def test_sweep_and_table1_on_the_device_write_the_cpu_tables(tmp_path):
    """Both read every insect's ticks on a noxious patch, which the kernel keeps for them."""
    device = device_env()
    sweep = [sys.executable, "-m", "spikinglab", "sweep", "--a-plus", "0.08", "--seeds", "2", "--ticks", "1000"]
    sweep += ["--runs", str(tmp_path)]
    table1 = [sys.executable, "-m", "spikinglab", "bench", "table1", "--seeds", "1", "--ticks", "1000"]
    table1 += ["--a-plus", "0.08", "--workers", "1"]
    for path, env in (("cuda", device), ("cpu", os.environ)):
        on = ["--device", "cuda"] if path == "cuda" else []
        for command in (sweep + ["--id", path], table1 + ["--out", str(tmp_path / f"table1-{path}")]):
            done = subprocess.run(command + on, cwd=ROOT, env=env, capture_output=True, text=True, timeout=280)
            assert done.returncode == 0, done.stderr[-2000:]
    sweeps = [json.loads((tmp_path / path / "table.json").read_text()) for path in ("cuda", "cpu")]
    tables = [json.loads((tmp_path / f"table1-{path}" / "table1.json").read_text()) for path in ("cuda", "cpu")]
    for rows, path in zip(sweeps + tables, ["cuda", "cpu"] * 2):
        for row in rows:
            assert row.pop("device") == path  # recorded where the population ran
            row.pop("seconds", None)
    assert sweeps[0] == sweeps[1] and sum(sweeps[1][0]["collisions_first_quarter"]) > 0
    assert tables[0] == tables[1] and len(tables[1]) == 8 and sum(sum(r["noxious_ticks"]) for r in tables[1]) > 0


def test_sweep_on_cuda_is_refused_in_one_line_without_a_device(tmp_path):
    if device_present():
        pytest.skip("a CUDA device is present here")
    command = [sys.executable, "-m", "spikinglab", "sweep", "--device", "cuda", "--runs", str(tmp_path)]
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "device='cuda' refused: " in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and not any(tmp_path.iterdir())
