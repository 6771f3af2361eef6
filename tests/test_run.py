"""`spikinglab run` as a user runs it: the run folder, the summary and plot, bad input, checkpoints."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.bus.batching import state_batch
from services.run_report import learning_rate, paper_time, rates_text
from spikinglab import World, brain_for, closed_loop, params_for
from spikinglab.bench.fuzz import KEY_OF

from .processes import ROOT, running_with, wait_for, wait_for_ticks


def spikinglab(*args, timeout=180, cwd=ROOT):
    return subprocess.run(
        [sys.executable, "-m", "spikinglab", *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def test_run_writes_summary_plot_weights_and_logs(tmp_path):
    done = spikinglab("run", "--ticks", 3000, "--seed", 4, "--a-plus", 0.04, "--runs", tmp_path, "--id", "r1")
    assert done.returncode == 0, done.stderr
    folder = tmp_path / "r1"
    for service in ("world", "brain", "recorder"):  # the world's beside its progress bar on the terminal
        assert " INFO " in (folder / f"{service}.log").read_text(), service
    assert "3000 ticks in" in (folder / "world.log").read_text() and "3000 ticks in" in done.stderr
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["parameters"]["ticks"] == 3000 and summary["parameters"]["seed"] == 4
    assert summary["parameters"]["a_plus"] == 0.04
    assert len(summary["collisions_per_1000_ticks"][0]) == 3
    assert sum(summary["collisions_per_1000_ticks"][0]) == summary["collisions"][0]
    assert set(summary["final_weights"]) == {f"{a}->{m}" for a in ("BLACK", "RED", "GREEN") for m in ("PAIN", "REWARD")}
    weights = load_weights(folder / "weights.npz", load_circuit("insect"))
    assert summary["final_weights"]["BLACK->PAIN"] == [round(float(weights[0, 0]), 4)]
    assert summary["initial_weights"]["BLACK->PAIN"] == [5.0]  # per agent too: the circuit's
    png = (folder / "collisions.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert f"written to {folder}" in done.stdout and "learning time" in done.stdout


def test_the_summary_names_the_command_main_was_given(tmp_path):
    """In-process, as an API caller runs it: the options given to main(argv), not this process's sys.argv."""
    from services.run import main

    argv = ["--ticks", "1000", "--seed", "2", "--preset", "netlogo", "--netlogo-seed", "7850"]
    argv += ["--no-record", "--quiet", "--runs", str(tmp_path), "--id", "a b"]
    assert main(argv) == 0
    summary = json.loads((tmp_path / "a b" / "summary.json").read_text())
    given = (
        f"--ticks 1000 --seed 2 --preset netlogo --netlogo-seed 7850 --no-record --quiet --runs {tmp_path} --id 'a b'"
    )
    assert summary["command"] == f"spikinglab run {given}"
    assert summary["parameters"]["seed"] == 2 and summary["run"] == "a b"
    assert summary["parameters"]["netlogo_seed"] == 7850  # what the arenas and headings come from
    assert summary["headline"]["collisions_first_quarter"] == summary["headline"]["collisions_last_quarter"]  # one bin


def test_per_agent_parameters_from_a_file_reach_world_and_brain(tmp_path):
    """`--params`: each insect runs with its row (one that does not learn keeps its weights); the
    file is kept in the run folder and its columns are in the summary."""
    study = tmp_path / "study.csv"
    study.write_text("# two insects\na_plus,a_minus,move_step\n0.04,0.04,1\n0,0,0.5\n")
    done = spikinglab(
        "run",
        "--ticks",
        3000,
        "--agents",
        2,
        "--params",
        study,
        "--runs",
        tmp_path,
        "--id",
        "p",
        "--no-record",
        "--quiet",
    )
    assert done.returncode == 0, done.stderr
    folder = tmp_path / "p"
    per_agent = json.loads((folder / "summary.json").read_text())["parameters"]["per_agent"]
    assert per_agent == {"a_plus": [0.04, 0.0], "a_minus": [0.04, 0.0], "move_step": [1.0, 0.5]}
    assert (folder / "params.csv").read_text() == study.read_text()
    # the first line names the rates as the file sets them and the file as given (the run reads its copy);
    # the report says its figures are the insects' mean
    said = done.stdout + done.stderr
    assert f"A+ = A- = [0.0, 0.04], world paper, per-agent parameters a_plus, a_minus, move_step from {study}," in said
    assert "collisions (mean of 2 insects): " in said and "weights (mean of 2 insects): " in said
    weights = load_weights(folder / "weights.npz", load_circuit("insect"))
    np.testing.assert_array_equal(weights[1], load_weights_initial()[0])  # A+ = A- = 0: nothing learnt
    assert not np.array_equal(weights[0], weights[1])
    distance = json.loads((folder / "metrics.json").read_text())["distance"]
    assert distance[1] < 0.75 * distance[0]  # half a patch a step against one
    assert not list(folder.glob("weights-*-tick*.npz"))  # a run that ended keeps no stop-gap weights


def test_a_trained_insect_runs_with_training_off(tmp_path):
    assert (
        spikinglab("run", "--ticks", 2000, "--runs", tmp_path, "--id", "train", "--a-plus", 0.08, "--quiet").returncode
        == 0
    )
    trained = load_weights(tmp_path / "train" / "weights.npz", load_circuit("insect"))
    assert not np.array_equal(trained, load_weights_initial())
    done = spikinglab(
        "run",
        "--ticks",
        2000,
        "--runs",
        tmp_path,
        "--id",
        "test",
        "--no-training",
        "--load",
        tmp_path / "train" / "weights.npz",
        "--quiet",
    )
    assert done.returncode == 0, done.stderr
    circuit = load_circuit("insect")
    np.testing.assert_array_equal(load_weights(tmp_path / "test" / "weights.npz", circuit), trained)
    summary = json.loads((tmp_path / "test" / "summary.json").read_text())
    assert summary["initial_weights"] == {  # the weights it started from: those loaded
        circuit.synapse_label(k): trained[:, k].round(4).tolist() for k in circuit.plastic_synapses
    }
    assert summary["parameters"]["load"] == str(tmp_path / "train" / "weights.npz")  # as given
    assert (tmp_path / "test" / "loaded-weights.npz").read_bytes() == (tmp_path / "train" / "weights.npz").read_bytes()


def load_weights_initial():
    return np.array([[s.weight for s in load_circuit("insect").synapses]])


def test_unknown_command_and_help():
    done = spikinglab("fly")
    assert done.returncode != 0 and "unknown command 'fly'" in done.stderr
    assert "run" in spikinglab("--help").stdout
    bench = spikinglab("bench", "--help")
    assert bench.returncode == 0 and "spikinglab bench {engine,loop,scale," in bench.stdout


def test_a_reader_that_stops_reading_ends_a_command_without_a_traceback():
    """`spikinglab ... | head`: the pipe closed before the command's output, as `head` does."""
    command = [sys.executable, "-m", "spikinglab", "bench", "scale", "--links", "--agents", "64", "--ticks", "5"]
    done = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    assert done.stdout is not None and done.stderr is not None
    done.stdout.close()
    err = done.stderr.read()
    assert done.wait(timeout=120) == 1
    assert "Traceback" not in err and "BrokenPipeError" not in err, err


def test_sweep_writes_the_table(tmp_path):
    done = spikinglab("sweep", "--a-plus", 0.02, 0.04, "--seeds", 2, "--ticks", 4000, "--runs", tmp_path, "--id", "s")
    assert done.returncode == 0, done.stderr
    rows = json.loads((tmp_path / "s" / "table.json").read_text())
    assert [r["a_plus"] for r in rows] == [0.02, 0.04] and all(len(r["learning_time"]) == 2 for r in rows)
    assert "| 0.04 | 7,000 |" in (tmp_path / "s" / "table.md").read_text()
    assert (tmp_path / "s" / "learning.png").read_bytes()[:4] == b"\x89PNG"


def test_ctrl_c_while_the_sweep_writes_leaves_its_table_whole_or_absent(tmp_path):
    """Ctrl-C as the sweep's first file appears (its figures take some tenths of a second more): one
    line and exit 130, and the folder holds the whole table and figures or none of them."""
    args = ("sweep", "--a-plus", "0.02", "--seeds", "1", "--ticks", "1000", "--runs", tmp_path, "--id", "s")
    sweep = subprocess.Popen(
        [sys.executable, "-m", "spikinglab", *map(str, args)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    folder = tmp_path / "s"
    wait_for(lambda: folder.exists() and any(folder.iterdir()), 180, "the sweep to write its first file")
    sweep.send_signal(signal.SIGINT)
    _, err = sweep.communicate(timeout=60)
    said = err.decode()
    assert sweep.returncode == 130, said
    assert "Traceback" not in said
    assert said.splitlines()[-1] in (
        "spikinglab sweep: interrupted, no table written",
        f"spikinglab sweep: interrupted, the table is written to {folder}/",
    )
    found = sorted(p.name for p in folder.iterdir()) if folder.exists() else []
    assert found in ([], ["learning.png", "table.json", "table.md", "table1.png"])


def test_sigterm_to_a_sweep_leaves_no_folder(tmp_path):
    """As Ctrl-C: one line, exit 130, and the sweep's folder, made at its start, is gone again."""
    args = ("sweep", "--a-plus", "0.02", "--seeds", "1", "--ticks", "200000", "--runs", tmp_path, "--id", "s")
    sweep = subprocess.Popen(
        [sys.executable, "-m", "spikinglab", *map(str, args)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    wait_for(lambda: (tmp_path / "s").exists(), 60, "the sweep to make its folder")
    sweep.terminate()
    _, err = sweep.communicate(timeout=60)
    assert (
        sweep.returncode == 130 and err.decode().splitlines()[-1] == "spikinglab sweep: interrupted, no table written"
    )
    assert not (tmp_path / "s").exists()


def test_benchmarks_run_and_end_with_json():
    done = spikinglab("bench", "engine", "--ticks", 2000, "--batch-ticks", 20, "--repeats", 1, "--rounds", 2)
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    assert set(figures) == {
        "single_ticks_per_s",
        "single_run_ticks_per_s",
        "batch1000_agent_ticks_per_s",
        "netlogo_single_ticks_per_s",
        "netlogo_single_run_ticks_per_s",
        "netlogo_batch1000_agent_ticks_per_s",
        "netlogo_over_phased_batch1000_median",
    }
    assert all(v > 0 for v in figures.values())
    assert spikinglab("bench", "nothing").returncode != 0
    fuzz = spikinglab("bench", "fuzz", "--examples", 10)
    assert fuzz.returncode == 0, fuzz.stderr
    figures = json.loads(fuzz.stdout.strip().splitlines()[-1])
    assert figures["escapes"] == 0 and set(figures["keys"]) == {"any key", *KEY_OF.values()}  # every kind's key
    assert all(counts["tried"] >= 10 for counts in figures["keys"].values())
    recorder = spikinglab("bench", "recorder", "--ticks", 1000, "--repeats", 2)
    assert recorder.returncode == 0, recorder.stderr
    figures = json.loads(recorder.stdout.strip().splitlines()[-1])
    assert figures["recorder_messages"] >= 2 * 1000 // state_batch(1) and figures["recording_mb"] > 0
    assert all(figures[k] > 0 for k in ("loop_ticks_per_s", "recorded_loop_ticks_per_s", "recorder_alone_ticks_per_s"))
    assert len(figures["recording_cost_by_pair"]) == 2  # both pairs ran, in turns


def start_run(tmp_path, *args, cwd=ROOT, runs=None):
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "spikinglab",
            "run",
            "--runs",
            runs or tmp_path,
            "--id",
            "r",
            "--quiet",
            *map(str, args),
        ],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_ctrl_c_writes_a_partial_result_and_leaves_nothing_running(tmp_path):
    run = start_run(tmp_path, "--ticks", 200_000)
    wait_for_ticks(tmp_path / "r")
    run.send_signal(signal.SIGINT)
    out, err = run.communicate(timeout=90)
    assert run.returncode == 130, err
    head = json.loads((tmp_path / "r" / "summary.json").read_text())["headline"]
    assert head["partial"] is True and 0 < head["ticks_done"] < 200_000
    assert "PARTIAL: interrupted after" in out
    assert (tmp_path / "r" / "weights.npz").exists()
    for plot in ("collisions.png", "trajectory.png"):  # their titles (PNG text) say so too
        assert f"PARTIAL: interrupted after {head['ticks_done']:,} of 200,000 ticks" in plot_title(
            tmp_path / "r" / plot
        )
    assert not running_with(str(tmp_path))
    world = World(params_for("paper"))
    brain = brain_for(world, load_circuit("insect"))
    closed_loop(world, brain, head["ticks_done"])
    weights = brain.engine.get_weights()
    got = json.loads((tmp_path / "r" / "summary.json").read_text())["all_final_weights"]
    assert got == {brain.circuit.synapse_label(k): weights[:, k].tolist() for k in range(weights.shape[1])}


def test_the_replay_line_names_the_runs_parts_and_not_an_earlier_try(tmp_path, capsys):
    """recording.rrd, then recording-from-tickN.rrd by N; not a part's earlier try that its
    recorder kept as .previous.rrd (a resume interrupted before its next checkpoint, resumed again)."""
    from services.run_report import report

    folder = tmp_path / "r"
    folder.mkdir()
    for name in ("recording-from-tick10000.rrd", "recording.rrd", "recording-from-tick5000.previous.rrd"):
        (folder / name).write_bytes(b"")
    (folder / "recording-from-tick5000.rrd").write_bytes(b"")
    head = {"learned": "no", "partial": False, "resumed_at": 10000, "ticks_done": 12000}
    head |= {"collisions_first_quarter": 9.0, "collisions_last_quarter": 1.0}
    parameters = {"learned_after": 5000, "a_plus": 0.02, "a_minus": 0.02, "agents": 1}
    report(
        folder,
        {"headline": head, "final_weights": {}, "learning_time": [None], "parameters": parameters, "ticks_per_s": 1},
    )
    replay = capsys.readouterr().out.splitlines()[-1]
    assert replay.endswith(
        " ".join(
            str(folder / name)
            for name in ("recording.rrd", "recording-from-tick5000.rrd", "recording-from-tick10000.rrd")
        )
    ), replay


def plot_title(path) -> str:
    from PIL import Image

    with Image.open(path) as png:
        return png.text["Title"]  # type: ignore[attr-defined]  # a PngImageFile's


def test_a_dead_service_ends_the_run_and_is_named(tmp_path):
    run = start_run(tmp_path, "--ticks", 200_000)
    wait_for_ticks(tmp_path / "r")
    (brain,) = [pid for pid, cmdline in running_with(str(tmp_path)).items() if "services.brain" in cmdline]
    os.kill(brain, signal.SIGKILL)
    killed = time.monotonic()
    _, err = run.communicate(timeout=60)
    assert time.monotonic() - killed < 10
    assert run.returncode == 1
    assert "the brain stopped (exit -9) before the world ended" in err and "Traceback" not in err
    assert (tmp_path / "r" / "FAILED.txt").exists() and not (tmp_path / "r" / "summary.json").exists()
    assert not running_with(str(tmp_path))


def test_a_run_stopped_in_its_first_thousand_ticks_still_plots(tmp_path):
    from services.run_report import plot

    summary = {
        "collisions_per_1000_ticks": [[]],
        "learning_time": [None],
        "parameters": {"a_plus": 0.02, "a_minus": 0.02, "seed": 0, "learned_after": 5000, "ticks": 100_000},
        "headline": {"partial": True, "ticks_done": 612},
    }
    plot(tmp_path, summary)  # no finished bin yet: an empty plot, not a traceback after Ctrl-C
    assert (tmp_path / "collisions.png").stat().st_size > 0


def test_a_run_of_no_whole_thousand_ticks_compares_no_quarters(capsys):
    """Its 2 collisions are in no bin: the quarters are not 0 and 0 but not compared."""
    from services.run_report import headline, report

    head = headline({"collisions_per_1000_ticks": [], "learning_time": [None], "ticks": 718, "partial": True}, 1)
    assert head["collisions_first_quarter"] is None and head["collisions_last_quarter"] is None
    parameters = {"learned_after": 5000, "a_plus": 0.02, "a_minus": 0.02, "agents": 1, "ticks": 100_000}
    summary = {"headline": head, "final_weights": {}, "learning_time": [None], "parameters": parameters}
    report(Path("r"), summary | {"ticks_per_s": 1})
    assert "collisions: none compared (no whole 1,000 ticks) (718 ticks, 1 ticks/s)" in capsys.readouterr().out


def test_an_interrupted_run_goes_on_with_resume_and_ends_as_an_uninterrupted_one(tmp_path):
    """Ctrl-C after a checkpoint, then `spikinglab run --resume`: the run ends with exactly the
    result of the same run never interrupted, from any folder and with the files it was given as
    they were; a new run never takes the interrupted one's folder."""
    study, arena = tmp_path / "study.csv", tmp_path / "arena.txt"
    study.write_text("a_plus,a_minus,move_step\n0.03,0.03,0.8\n")
    arena.write_text("##########\n#S...R...#\n#........#\n#..G.....#\n##########\n")
    options = ("--ticks", 12000, "--seed", 5, "--checkpoint-every", 4000, "--params", study)
    options += ("--map", arena.name)  # as given in tmp_path: a path relative to where the run started
    whole = spikinglab(
        "run", *options, "--runs", tmp_path / "whole", "--id", "r", "--quiet", "--no-record", cwd=tmp_path
    )
    assert whole.returncode == 0, whole.stderr
    assert not (tmp_path / "whole" / "r" / "checkpoint").exists()  # a whole run keeps no checkpoints
    run = start_run(tmp_path, *options, cwd=tmp_path, runs=".")  # the run folder as ./r, resumed below by another path
    kept = tmp_path / "r" / "checkpoint" / "world.npz"
    deadline = time.monotonic() + 120
    while not kept.exists():
        assert time.monotonic() < deadline and run.poll() is None, "no checkpoint was kept"
        time.sleep(0.05)
    run.send_signal(signal.SIGINT)
    out, err = run.communicate(timeout=90)
    assert run.returncode == 130, err
    assert "go on from its checkpoint at tick 4,000: spikinglab run --resume r\n" in out
    again = spikinglab("run", *options, "--runs", tmp_path, "--id", "r", "--quiet", cwd=tmp_path)
    assert again.returncode == 2 and f"go on with it: spikinglab run --resume {tmp_path / 'r'}" in again.stderr
    assert spikinglab("run", "--resume", tmp_path / "r", "--ticks", 50).returncode == 2  # only its own options
    for damaged in ("world.npz", "brain-*-tick4000.npz"):  # truncated: the run would go on without its learning
        copy = tmp_path / damaged.partition("-")[0]
        shutil.copytree(tmp_path / "r", copy)
        (path,) = (copy / "checkpoint").glob(damaged)
        path.write_bytes(path.read_bytes()[:100])
        refused = spikinglab("run", "--resume", copy, "--quiet")
        assert (
            refused.returncode == 2
            and f"cannot resume the run in {copy}: {path}: not a run checkpoint" in refused.stderr
        )
    study.write_text("a_plus,a_minus,move_step\n0.01,0.01,1.2\n")  # the run goes on with the files it began with
    arena.write_text("############\n#S.........#\n############\n")
    resumed = spikinglab("run", "--resume", tmp_path / "r", "--quiet", "--no-record")  # from the checkout
    assert resumed.returncode == 0, resumed.stderr
    assert "recording: PARTIAL, this part, from tick 4,000, was not recorded (--no-record)" in resumed.stdout
    got, want = (
        json.loads((folder / "summary.json").read_text()) for folder in (tmp_path / "r", tmp_path / "whole" / "r")
    )
    assert got["headline"]["resumed_at"] == 4000 and not got["headline"]["partial"]
    for key in ("collisions_per_1000_ticks", "collisions", "food", "learning_time", "all_final_weights"):
        assert got[key] == want[key], key
    assert not (tmp_path / "r" / "checkpoint").exists() and not (tmp_path / "r" / "FAILED.txt").exists()
    nothing = spikinglab("run", "--resume", tmp_path / "r")
    assert nothing.returncode == 2 and "nothing to resume" in nothing.stderr


def test_a_resumed_run_is_watched_as_its_resume_command_says(tmp_path):
    """How a run is watched is the resume's own choice: a run started --quiet --no-record goes on
    shown and recorded unless the resume says so again; what the run is stays as it was started."""
    from services.run import arguments, parser

    folder = tmp_path / "r"
    folder.mkdir()
    (folder / "command.json").write_text(json.dumps({"argv": ["--ticks", "8000", "--quiet", "--no-record"]}))
    plain = arguments(parser(), ["--resume", str(folder)])
    assert (plain.quiet, plain.no_record, plain.ticks) == (False, False, 8000)
    again = arguments(parser(), ["--resume", str(folder), "--quiet", "--no-record"])
    assert (again.quiet, again.no_record, again.ticks) == (True, True, 8000)
    viewed = arguments(parser(), ["--resume", str(folder), "--view"])  # refused before: --no-record was the start's
    assert (viewed.view, viewed.no_record) == (True, False)


def test_the_replay_line_names_a_viewer_that_exists_from_any_folder(tmp_path, monkeypatch):
    from services.run_report import viewer_shown

    monkeypatch.chdir(tmp_path)  # a user who runs spikinglab outside the checkout (it printed .venv/bin/rerun)
    shown = viewer_shown()
    assert os.path.isfile(shown) and os.access(shown, os.X_OK), shown


def test_a_circuit_whose_rates_differ_is_named_with_both_and_not_given_the_papers_time():
    circuit = load_circuit("fast_learner")  # a searched circuit: A+ and A- differ
    rates = {which: learning_rate(circuit, which) for which in ("a_plus", "a_minus")}
    assert rates_text(rates) == f"A+ = {rates['a_plus']}, A- = {rates['a_minus']}" != "A+ = A- = 0.02"
    assert rates_text({"a_plus": 0.02, "a_minus": 0.02}) == "A+ = A- = 0.02"
    assert paper_time({"a_plus": 0.04, "a_minus": 0.04}) == 7_000
    assert paper_time({"a_plus": 0.04, "a_minus": 0.05}) is None  # Table 1 sets both to one A


def test_sigterm_before_the_run_begins_ends_every_process_at_once(tmp_path):
    """SIGTERM to `spikinglab run` alone (not its process group, as a terminal's Ctrl-C would),
    as its services start: the world ends before its run began, so brain and recorder, which wait
    for a run, are stopped rather than waited for; one line names it, exit 130, nothing left."""
    run = start_run(tmp_path, "--ticks", 200_000)
    wait_for(lambda: (tmp_path / "r" / "brain.log").exists(), 60, "the services to start")
    run.send_signal(signal.SIGTERM)
    sent = time.monotonic()
    _, err = run.communicate(timeout=100)
    assert run.returncode == 130, err
    assert time.monotonic() - sent < 30  # the brain's and recorder's stop, not FINISH_S's 120 s
    assert "Traceback" not in err and "interrupted before the first tick" in err
    assert not running_with(str(tmp_path))


def test_one_ctrl_c_after_the_world_ended_still_writes_the_summary(tmp_path):
    """The world has run all its ticks and the recorder is still writing (held here with SIGSTOP):
    one Ctrl-C stops brain and recorder as the first Ctrl-C does, each writing what it has, and the
    run's summary is written; it is not taken as a second Ctrl-C (no result)."""
    run = start_run(tmp_path, "--ticks", 10_000)
    folder, brain = tmp_path / "r", tmp_path / "r" / "brain.log"
    wait_for(lambda: brain.exists() and " brain for " in brain.read_text(), 120, "the run to start")
    (recorder,) = [pid for pid, cmdline in running_with(str(tmp_path)).items() if "services.recorder" in cmdline]
    os.kill(recorder, signal.SIGSTOP)
    try:
        wait_for(lambda: (folder / "metrics.json").exists(), 120, "the world to end")
        wait_for(lambda: "services.world" not in str(running_with(str(tmp_path))), 60, "the world to exit")
        time.sleep(0.5)  # the launcher has seen it and waits for the recorder
        run.send_signal(signal.SIGINT)
        time.sleep(0.3)
    finally:
        os.kill(recorder, signal.SIGCONT)
    _, err = run.communicate(timeout=90)
    assert run.returncode == 130, err
    assert "interrupted: the brain and the recorder write what they have" in err and "Traceback" not in err
    head = json.loads((folder / "summary.json").read_text())["headline"]
    assert head["partial"] is False and head["ticks_done"] == 10_000
    assert not (folder / "FAILED.txt").exists() and not running_with(str(tmp_path))


def test_two_runs_never_share_a_folder(tmp_path):
    """A run started in the same second with the same seed gets a folder of its own; a run given the
    folder of a run going on now is refused before anything starts."""
    from services.run_folder import hold, new_folder

    first, second = new_folder(tmp_path, 3), new_folder(tmp_path, 3)
    assert first != second and first.is_dir() and second.is_dir()
    assert second.name in (f"{first.name}-2", second.name.split("-seed")[0] + "-seed3")  # or the next second's
    busy = tmp_path / "busy"
    busy.mkdir()
    hold(busy)  # as the run that has it does, until its process ends
    refused = spikinglab("run", "--runs", tmp_path, "--id", "busy", "--ticks", 1000)
    assert refused.returncode == 2
    assert f"{busy} is in use by another spikinglab run now: choose another --id" in refused.stderr
    assert not list(busy.iterdir())  # nothing written over the other run's
