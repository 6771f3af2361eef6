"""The Python API as docs/api.md shows it, and the example that uses it."""

import subprocess
import sys

import spikinglab

from .processes import ROOT


def test_every_api_name_loads():
    assert sorted(spikinglab.__all__) == sorted(spikinglab.API)
    for name in spikinglab.__all__:
        assert getattr(spikinglab, name) is not None, name


def test_the_example_trains_a_population():
    done = subprocess.run(
        [sys.executable, ROOT / "examples" / "train_population.py", "30000"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    rows = [line.split() for line in lines[1:7]]
    collisions = [int(r[1]) for r in rows]
    weights = [float(r[2]) for r in rows]
    assert collisions[-1] < collisions[0] / 2  # the population learns
    assert weights == sorted(weights) and weights[-1] > weights[0]  # BLACK->PAIN potentiated
    assert "of 8 insects learned within 30,000 ticks" in lines[-1]
