"""The searched circuit (services/brain/circuits/fast_learner.toml, docs/results.md) holds the
search's result and learns on a held-out seed that the search never saw, where the default insect
circuit does not; the search script (examples/search_fast_learner.py) refuses options it cannot run."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.brain.circuit import load_circuit
from spikinglab import evaluate

from .examples import EXAMPLES, example

SEED = 2  # a held-out seed (0-31; the search used 1000-1047 and 2000-2047): fast_learner learns at 2,095
TICKS = 10_000  # room for the learning time and the 5,000 collision-free ticks after it
SCRIPT = EXAMPLES / "search_fast_learner.py"
# a search and a report of seconds, so that a bad option the script once accepted ends the test soon
TINY_SEARCH = ["--generations", "1", "--population", "2", "--seeds", "1", "--ticks", "1000"]
TINY_REPORT = ["--report", "--report-ticks", "1000", "--report-seeds", "1"]


def search_script():
    return example("search_fast_learner")


def test_the_circuit_file_holds_the_search_result_and_the_search_space_holds_the_insect():
    search, insect = search_script(), load_circuit("insect")
    shipped = dataclasses.replace(load_circuit("fast_learner"), source="")
    assert dataclasses.replace(search.circuit_of(search.FOUND), source="") == shipped
    assert search.FOUND != search.INSECT
    rebuilt = search.circuit_of(search.INSECT)  # the insect's own values give the insect back
    assert (rebuilt.synapses, rebuilt.inputs) == (insect.synapses, insect.inputs)
    assert [dataclasses.replace(t, name="") for t in rebuilt.neuron_types] == [
        dataclasses.replace(t, name="") for t in insect.neuron_types
    ]


def test_fast_learner_learns_on_a_held_out_seed_where_the_insect_does_not():
    fast = evaluate({}, TICKS, [SEED], circuit="fast_learner")
    insect = evaluate({}, TICKS, [SEED], circuit="insect")
    assert 0 <= fast["learning_time"][0, 0] <= TICKS - 5_000
    assert insect["learning_time"][0, 0] == -1


def test_the_search_counts_an_insect_that_stands_still_as_never_learned():
    search = search_script()
    result = {"learning_time": np.array([0, 100, -1]), "distance": np.array([0.0, 1_000.0, 1_000.0])}
    assert search.learning_times(result, 30_000).tolist() == [60_000, 100, 60_000]


def run_script(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """The script run as a user would; in `cwd`, a test's own folder: a report writes its plot there."""
    return subprocess.run([sys.executable, SCRIPT, *args], cwd=cwd, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    "given, said",
    [
        ("--population 1", "argument --population: must be at least 2, got 1"),  # was cma's traceback
        ("--seeds 0", "argument --seeds: must be at least 1, got 0"),  # was services/loop.py's traceback
        ("--ticks 10", "argument --ticks: must be at least 1,000, got 10"),  # ran, and no seed could learn
        ("--sigma -1", "argument --sigma: must be a number above 0, got -1"),
        ("--start a_plus=5", "argument --start: must be 0.005 .. 0.8 for a_plus, got 5"),  # cma's traceback
        ("--report --report-seeds 0", "argument --report-seeds: must be at least 1, got 0"),
        ("--report --report-ticks 10", "argument --report-ticks: must be at least 1,000, got 10"),
        ("--plot curves.png", "argument --plot: only with --report"),  # was ignored: a search writes no plot
        ("--report --generations 3", "argument --generations: not with --report"),  # was ignored by the report
    ],
)
def test_the_script_refuses_a_bad_option_in_one_line_before_it_runs(given, said, tmp_path):
    done = run_script(*(TINY_REPORT if "--report" in given else TINY_SEARCH), *given.split(), cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.splitlines() == [
        f"search_fast_learner.py: {said} (see search_fast_learner.py --help)"
    ]
    assert done.stdout == ""


def test_the_help_lists_each_option_under_the_mode_that_takes_it():
    """A search option given to --report is refused: the help said nothing of which was which."""
    script = search_script()
    help_text = script.parser().format_help()
    search_part, report_part = help_text.split("the report (with --report):")
    assert "a search (without --report):" in search_part
    for option, (_, modes) in script.MODES.items():
        assert f"  {option} " in (report_part if modes == ("--report",) else search_part), option


def test_the_report_refuses_a_plot_it_cannot_write_before_its_runs(tmp_path):
    """The plot is written last: it raised FileNotFoundError after the whole report had run."""
    (tmp_path / "file").touch()
    done = run_script(*TINY_REPORT, "--plot", str(tmp_path / "file" / "curves.png"), cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.splitlines() == [
        f"search_fast_learner.py: argument --plot: cannot write {tmp_path / 'file' / 'curves.png'}: "
        f"{tmp_path / 'file'} is a file, not a folder (see search_fast_learner.py --help)"
    ]
    assert done.stdout == ""


def test_the_report_writes_its_plot_in_the_current_folder_as_its_help_says(tmp_path):
    """--report wrote docs/fast-learner.png, the docs' own figure, and --help did not say so."""
    assert "(default fast-learner.png, in the current folder;" in " ".join(
        run_script("--help", cwd=tmp_path).stdout.split()
    )
    done = run_script(*TINY_REPORT, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1] == "wrote fast-learner.png"
    assert [path.name for path in tmp_path.iterdir()] == ["fast-learner.png"]
