"""`spikinglab run` as a user runs it: the run folder, the summary and plot, bad input, checkpoints."""

import json
import subprocess
import sys

import numpy as np

from spikinglab.brain.checkpoint import load_weights
from spikinglab.brain.circuit import load_circuit

from .processes import ROOT


def spikinglab(*args, timeout=180):
    return subprocess.run([sys.executable, "-m", "spikinglab.cli", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_run_writes_summary_plot_and_weights(tmp_path):
    done = spikinglab("run", "--ticks", 3000, "--seed", 4, "--a-plus", 0.04, "--runs", tmp_path, "--id", "r1", "--quiet")
    assert done.returncode == 0, done.stderr
    folder = tmp_path / "r1"
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["parameters"]["ticks"] == 3000 and summary["parameters"]["seed"] == 4
    assert summary["parameters"]["a_plus"] == 0.04
    assert len(summary["collisions_per_1000_ticks"][0]) == 3
    assert sum(summary["collisions_per_1000_ticks"][0]) == summary["collisions"][0]
    assert set(summary["final_weights"]) == {f"{a}->{m}" for a in ("BLACK", "RED", "GREEN") for m in ("PAIN", "REWARD")}
    weights = load_weights(folder / "weights.npz", load_circuit("insect"))
    assert summary["final_weights"]["BLACK->PAIN"] == [round(float(weights[0, 0]), 4)]
    png = (folder / "collisions.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert f"written to {folder}" in done.stdout and "learning time" in done.stdout


def test_a_trained_insect_runs_with_training_off(tmp_path):
    assert spikinglab("run", "--ticks", 2000, "--runs", tmp_path, "--id", "train", "--a-plus", 0.08,
                      "--quiet").returncode == 0
    trained = load_weights(tmp_path / "train" / "weights.npz", load_circuit("insect"))
    assert not np.array_equal(trained, load_weights_initial())
    done = spikinglab("run", "--ticks", 2000, "--runs", tmp_path, "--id", "test", "--no-training",
                      "--load", tmp_path / "train" / "weights.npz", "--quiet")
    assert done.returncode == 0, done.stderr
    np.testing.assert_array_equal(load_weights(tmp_path / "test" / "weights.npz", load_circuit("insect")), trained)


def load_weights_initial():
    return np.array([[s.weight for s in load_circuit("insect").synapses]])


def test_bad_input_is_named_and_nothing_starts(tmp_path):
    bad_circuit = tmp_path / "bad.toml"
    bad_circuit.write_text('[neurons]\nA = "regular"\n[[synapses]]\nfrom = "A"\nto = "B"\nweight = 5\ndelay = 1\n')
    done = spikinglab("run", "--circuit", bad_circuit, "--runs", tmp_path)
    assert done.returncode == 2
    assert f"{bad_circuit}: synapses[0] (A -> B): to: unknown neuron 'B'" in done.stderr
    bad_map = tmp_path / "bad.txt"
    bad_map.write_text("###\n#S?\n###\n")
    done = spikinglab("run", "--map", bad_map, "--runs", tmp_path)
    assert done.returncode == 2 and f"{bad_map}: line 2, column 3: unknown cell '?'" in done.stderr
    done = spikinglab("run", "--load", tmp_path / "missing.npz", "--runs", tmp_path)
    assert done.returncode == 2 and "missing.npz: not a weights checkpoint" in done.stderr
    assert not any(p.is_dir() for p in tmp_path.iterdir())  # no run folder was made


def test_unknown_command_and_help():
    done = spikinglab("fly")
    assert done.returncode != 0 and "unknown command 'fly'" in done.stderr
    assert "run" in spikinglab("--help").stdout


def test_sweep_writes_the_table(tmp_path):
    done = spikinglab("sweep", "--a-plus", 0.02, 0.04, "--seeds", 2, "--ticks", 4000, "--runs", tmp_path, "--id", "s")
    assert done.returncode == 0, done.stderr
    rows = json.loads((tmp_path / "s" / "table.json").read_text())
    assert [r["a_plus"] for r in rows] == [0.02, 0.04] and all(len(r["learning_time"]) == 2 for r in rows)
    assert "| 0.04 | 7,000 |" in (tmp_path / "s" / "table.md").read_text()
    assert (tmp_path / "s" / "learning.png").read_bytes()[:4] == b"\x89PNG"


def test_benchmarks_run_and_end_with_json():
    done = spikinglab("bench", "engine", "--ticks", 2000, "--batch-ticks", 20, "--repeats", 1)
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    assert set(figures) == {"single_ticks_per_s", "batch1000_agent_ticks_per_s", "netlogo_single_ticks_per_s",
                            "netlogo_batch1000_agent_ticks_per_s"}
    assert all(v > 0 for v in figures.values())
    assert spikinglab("bench", "nothing").returncode != 0
