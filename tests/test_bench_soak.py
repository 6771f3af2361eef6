"""bench soak's memory samples (spikinglab/bench/soak.py)."""

import subprocess
import sys

from spikinglab.bench.soak import sample_until


def test_a_sample_taken_after_every_process_ended_is_left_out(capsys):
    """The last sleep outlives the processes: nothing left to read, no empty line printed."""
    short = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.3)"])
    samples, wall = sample_until({"world": short}, short, 3.0)
    assert samples == [] and wall >= 3.0
    assert capsys.readouterr().out == ""
