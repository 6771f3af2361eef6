"""The recorder: a run's .rrd read back holds what the world and the brain did."""

import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from rerun.chunk import RrdReader
from rerun.error_utils import RerunWarning

from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.bus import keys
from services.bus.batching import state_batch
from services.loop import brain_for, closed_loop
from services.world.world import SENSORS, World, generate_map, params_for

from ..processes import ROOT, Watcher, connecting, endpoint, finish, start, ticks_in, wait_for, world_and_brain
from ..recordings import read

TICKS, SEED = 3000, 3


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "spikinglab",
            "run",
            "--ticks",
            str(TICKS),
            "--seed",
            str(SEED),
            "--a-plus",
            "0.04",
            "--runs",
            str(runs),
            "--id",
            "r",
            "--quiet",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    replay = next(line for line in done.stdout.splitlines() if line.startswith("replay it: ")).split()
    assert (ROOT / replay[2]).exists() and (runs / "r" / "recording.rrd").samefile(replay[3])  # works where it ran
    world = World(params_for("paper"), seed=SEED)
    brain = brain_for(world, load_circuit("insect").with_learning_rate(0.04))
    pos, sensed, spikes = [], [], np.zeros(len(brain.circuit.node_names), np.int64)

    def keep(t):
        pos.append(world.pos[0].copy())
        sensed.append(dict(zip(SENSORS, world.sensors[0])))
        spikes[:] += brain.engine.spiked[0]

    closed_loop(world, brain, TICKS, keep)
    return runs / "r", read(runs / "r" / "recording.rrd"), np.array(pos), spikes, world, sensed


def view(xy, params):
    return np.column_stack([xy[:, 0] - params.x_min + 0.5, (params.height - 1) - (xy[:, 1] - params.y_min) + 0.5])


def test_map_and_positions_are_the_worlds(recorded_run):
    folder, data, pos, _, world, _ = recorded_run
    images = data["/world/map"]
    first = np.frombuffer(bytes(images["SegmentationImage:buffer"][0][0]), np.uint8)
    grid0 = generate_map(world.params, SEED)
    np.testing.assert_array_equal(first.reshape(grid0.shape[1], grid0.shape[0]), grid0[:, ::-1].T)
    # food eaten: the last frame is the world's grid at the end
    last = np.frombuffer(bytes(images["SegmentationImage:buffer"][-1][0]), np.uint8)
    np.testing.assert_array_equal(last.reshape(grid0.shape[1], grid0.shape[0]), world.grid[0][:, ::-1].T)
    assert len(images["tick"]) == world.metrics.food[0] + 1  # one frame per food eaten
    insects = data["/world/insects"]
    assert insects["tick"] == list(range(TICKS))  # every tick, none dropped
    recorded = np.array([p[0] for p in insects["Points2D:positions"]])
    np.testing.assert_allclose(recorded, view(pos, world.params), atol=1e-4)  # float32 in the file


def test_spikes_weights_and_learning_curve_are_the_brains(recorded_run):
    folder, data, _, spikes, world, _ = recorded_run
    circuit = load_circuit("insect")
    for k, name in enumerate(circuit.node_names):
        raster = data.get(f"/brain/agent0/spikes/{k:02d}_{name}", {}).get("tick", [])
        assert len([t for t in raster if t is not None]) == spikes[k], name
    weights = data["/brain/agent0/weights"]
    assert weights["tick"][-1] == TICKS - 1 and weights["tick"][0] == state_batch(1) - 1  # after each batch
    saved = load_weights(folder / "weights.npz", circuit)[0, circuit.plastic_synapses]
    np.testing.assert_array_equal(weights["Scalars:scalars"][-1], saved)
    potentials = data["/brain/agent0/potentials"]
    assert len(potentials["tick"]) == TICKS and len(potentials["Scalars:scalars"][0]) == len(circuit.neuron_names)
    curve = data["/learning/collisions_per_1000"]
    metrics = json.loads((folder / "metrics.json").read_text())
    assert [v[0] for v in curve["Scalars:scalars"]] == metrics["collisions_per_1000_ticks"][0]
    texts = [t[0] for t in data["/events"]["TextLog:text"]]
    assert f"run ended at tick {TICKS}" in texts
    # a run that ended warns of nothing: world and brain leaving after their final batches is no fault
    warned = [text for text, level in zip(texts, data["/events"]["TextLog:level"]) if level != ["INFO"]]
    assert warned == []
    assert RrdReader(str(folder / "recording.rrd")).blueprints  # the layout is in the file


def headless_viewers() -> set[int]:
    """Process ids of running headless Rerun viewers (of anyone: compared before and after)."""
    out = subprocess.run(["ps", "-eo", "pid=,args="], capture_output=True, text=True).stdout
    return {int(line.split()[0]) for line in out.splitlines() if "rerun" in line and "--headless" in line}


def test_screenshot_of_the_replay_is_not_blank(recorded_run, tmp_path):
    from matplotlib.image import imread

    folder = recorded_run[0]
    before = headless_viewers()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "spikinglab",
            "screenshot",
            str(folder / "recording.rrd"),
            "--out",
            str(tmp_path / "replay.png"),
            "--tick",
            "2500",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert headless_viewers() == before  # the viewer it started is gone, the real one behind the wrapper too
    image = imread(tmp_path / "replay.png")[..., :3]
    assert image.shape[0] >= 800 and image.shape[1] >= 1400
    assert image.std() > 0.05  # not one flat colour
    # the map is drawn: predator red and food green pixels are there
    red = (image[..., 0] > 0.75) & (image[..., 1] < 0.3) & (image[..., 2] < 0.3)
    green = (image[..., 1] > 0.6) & (image[..., 0] < 0.4) & (image[..., 2] < 0.45)
    assert red.sum() > 500 and green.sum() > 500


def test_a_killed_recorder_leaves_a_readable_file(tmp_path):
    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    recorder = start(
        "record",
        *connecting(world_ep, brain_ep),
        "--out",
        tmp_path / "rec.rrd",
        "--flush-every",
        500,
        log=tmp_path / "recorder.log",
    )
    world, brain = world_and_brain(tmp_path, ["--ticks", 20000])
    try:
        wait_for(
            lambda: (tmp_path / "rec.rrd").exists() and (tmp_path / "rec.rrd").stat().st_size > 200_000,
            60,
            "some of the run in the file",
        )
        recorder.kill()
        assert finish(world, 120, tmp_path / "world.log") == 0  # the run goes on without it
        assert finish(brain, 30, tmp_path / "brain.log") == 0
    finally:
        for p in (recorder, world, brain):
            p.kill()
    with pytest.warns(RerunWarning, match="no footer"):  # killed before it could write one: still readable
        data = read(tmp_path / "rec.rrd")
    ticks = data["/world/insects"]["tick"]
    assert ticks[0] == 0 and 500 <= len(ticks) < 20000
    assert ticks == list(range(len(ticks)))  # complete up to where it stopped


def test_a_late_recorder_says_from_which_tick_it_has_data(tmp_path):
    """A recorder that joins a run at tick > 1,500 says from which tick it has data, and has none
    before. The run goes on until the recorder has joined and then ends by Ctrl-C, so that a slow
    machine cannot end it before the recorder is there."""
    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    early = Watcher([world_ep, brain_ep], [keys.world_state("insect"), keys.brain_state("insect")])
    world, brain = world_and_brain(tmp_path, ["--ticks", 10**7])
    recorder_log = tmp_path / "recorder.log"
    try:
        wait_for(lambda: len(ticks_in(early.messages[keys.world_state("insect")])) > 1500, 60, "the run to get going")
        recorder = start("record", *connecting(world_ep, brain_ep), "--out", tmp_path / "late.rrd", log=recorder_log)
        wait_for(lambda: "recording group" in recorder_log.read_text(), 60, "the recorder to subscribe")
        # the states are lossy on the bus: under load the first ones to the recorder may be dropped
        for stream in ("world", "brain"):
            said = f"the {stream}'s state comes in from tick"
            wait_for(lambda said=said: said in recorder_log.read_text(), 60, f"the {stream}'s state at the recorder")
        joined = len(ticks_in(early.messages[keys.world_state("insect")]))
        wait_for(lambda: len(ticks_in(early.messages[keys.world_state("insect")])) > joined + 500, 60, "more ticks")
        world.send_signal(signal.SIGINT)  # ends the run at the tick it is in, for the brain and the recorder too
        assert finish(world, 60, tmp_path / "world.log") == 130
        assert finish(recorder, 60, recorder_log) == 0
    finally:
        early.close()
        world.kill()
        brain.kill()
    data = read(tmp_path / "late.rrd")
    texts = [t[0] for t in data["/events"]["TextLog:text"]]
    late = [t for t in texts if "the recorder started late" in t]
    assert len(late) == 1
    starts = re.search(r"recording starts at tick (\d+)", late[0])
    assert starts, late[0]
    # (not bounded by `joined`: a loaded machine's watcher counts ticks behind the world's own)
    first, ticks = int(starts.group(1)), data["/world/insects"]["tick"]
    assert 1500 < first <= ticks[0] < ticks[-1]  # joined late, no data before the tick it names, data after


def test_each_run_gets_its_own_recording(tmp_path):
    """Two runs one after the other on one recorder (--forever) and one brain: the second goes to
    a file of its own, named by its run id, with its map and every tick from 0 (held while the
    first run could still go on); the first file holds only the first run."""
    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    recorder = start(
        "record",
        *connecting(world_ep, brain_ep),
        "--out",
        tmp_path / "rec.rrd",
        "--forever",
        log=tmp_path / "recorder.log",
    )
    brain = start("brain", "--listen", brain_ep, "--connect", world_ep, "--publish-state", log=tmp_path / "brain.log")
    try:
        for seed in (1, 2):
            world = start(
                "world",
                "--listen",
                world_ep,
                "--ticks",
                2000,
                "--seed",
                seed,
                "--publish-state",
                log=tmp_path / f"world{seed}.log",
            )
            assert finish(world, 120, tmp_path / f"world{seed}.log") == 0
        runs = re.findall(
            r"run ([0-9a-f]{16}): 2000 ticks", "".join((tmp_path / f"world{s}.log").read_text() for s in (1, 2))
        )
        second = tmp_path / f"rec-{runs[1]}.rrd"
        wait_for(
            lambda: "run " + runs[1] + " starts" in (tmp_path / "recorder.log").read_text(),
            30,
            "the recorder to take the second run",
        )
        time.sleep(2)  # its last batches
        recorder.terminate()
        assert finish(recorder, 30, tmp_path / "recorder.log") == 0
    finally:
        for p in (recorder, brain):
            p.kill()
    first, then = read(tmp_path / "rec.rrd"), read(second)
    for data in (first, then):
        assert data["/world/insects"]["tick"] == list(range(2000))
        assert "/world/map" in data  # the second run's map came while the first could still go on
    assert first["/world/insects"] != then["/world/insects"]  # another seed: another path


def test_vision_rays_and_pain_marks_are_what_the_insect_sensed(recorded_run):
    """Tick t's ray runs from where the insect stood after tick t - 1 as far as the nearest smell (4
    patches when none); a pain mark is there in the ticks it felt pain, and only then."""
    _, data, pos, _, world, sensed = recorded_run
    rays = data["/world/vision/agent0"]
    assert rays["tick"] == list(range(TICKS))
    strips = np.array([row[0] for row in rays["LineStrips2D:strips"]])  # [T, 2 ends, 2]
    np.testing.assert_allclose(strips[1:, 0], view(pos[:-1], world.params), atol=1e-4)
    nearest = [
        min([s[n] for n in ("smell_black", "smell_red", "smell_green") if not np.isnan(s[n])], default=4.0)
        for s in sensed
    ]
    np.testing.assert_allclose(np.linalg.norm(strips[:, 1] - strips[:, 0], axis=1), nearest, atol=1e-4)
    pain = data["/world/pain"]
    felt = [t for t, marks in zip(pain["tick"], pain["Points2D:positions"]) if marks]
    assert felt == [t for t, s in enumerate(sensed) if not np.isnan(s["pain"])] and felt


def test_brain_states_unlike_the_first_are_refused_whole_even_before_the_layout(tmp_path):
    """The recorder joins a brain's batches at each flush: one of other agents, nodes, neurons or
    synapses would not join (a forged one once ended the recorder with a ValueError there)."""
    import msgspec
    import rerun as rr

    from services.brain.node import layout
    from services.bus.schemas import Array, BrainState, BusError, new_run_id
    from services.recorder.recorder import Recorder

    circuit, run = load_circuit("insect"), new_run_id()
    nodes, neurons, synapses = len(circuit.node_names), len(circuit.neuron_names), len(circuit.synapses)

    def state(tick, agents=1, nodes=nodes, neurons=neurons, synapses=synapses):
        return BrainState(
            tick=tick,
            run=run,
            spiked=Array.of(np.ones((10, agents, nodes), np.uint8)),
            potentials=Array.of(np.zeros((10, agents, neurons), np.float32)),
            weights=Array.of(np.ones((agents, synapses))),
        )

    rec = rr.RecordingStream("spikinglab-test", recording_id="t")
    rec.save(str(tmp_path / "t.rrd"))
    recorder = Recorder(rec, flush_every=15)
    recorder.on(state(0))
    for unlike in (
        state(10, agents=2),
        state(10, nodes=nodes + 1),
        state(10, neurons=neurons - 1),
        state(10, synapses=synapses + 1),
    ):
        with pytest.raises(BusError, match="does not fit the recording: a brain state of"):
            recorder.on(unlike)
    recorder.on(layout(circuit, 0, run))
    recorder.on(state(10))  # past flush_every: the two batches are joined and sent
    with pytest.raises(BusError, match="does not fit the recording"):
        recorder.on(msgspec.structs.replace(layout(circuit, 0, run), neurons=neurons - 1))
    recorder.close()
    rec.flush()
    rec.disconnect()
    potentials = read(tmp_path / "t.rrd")["/brain/agent0/potentials"]
    assert potentials["tick"] == list(range(20))


def test_the_trail_is_cut_where_the_insect_was_put_back_and_nowhere_else(tmp_path):
    """The trail keeps every TRAIL_STEP-th position: ordinary moves between two of them (several
    patches) are lines, the put-back at the start (one tick's jump) is no line."""
    import rerun as rr

    from services.bus.schemas import Array, WorldMap, WorldState, new_run_id
    from services.recorder.recorder import Recorder

    params, run, ticks = params_for("paper"), new_run_id(), 200
    angle = np.arange(ticks) * 1.5 / 10  # 1.5 patches a tick (move and push) around a circle of radius 10
    pos = np.column_stack([100 + 10 * np.cos(angle), 25 + 10 * np.sin(angle)])
    pos[120:] = [100, 50]  # tick 120: put back at a start 15 patches away, and stays there
    rec = rr.RecordingStream("spikinglab-test", recording_id="trail")
    rec.save(str(tmp_path / "trail.rrd"))
    recorder = Recorder(rec)
    grid = generate_map(params, 0)[None]
    recorder.on(WorldMap(tick=0, run=run, grid=Array.of(grid), x_min=params.x_min, y_min=params.y_min))
    recorder.on(
        WorldState(
            tick=0,
            run=run,
            sensor_names=SENSORS,
            sensors=Array.of(np.full((ticks, 1, len(SENSORS)), np.nan)),
            pos=Array.of(pos[:, None]),
            heading=Array.of(np.zeros((ticks, 1))),
            events=Array.of(np.zeros((ticks, 1, 4), np.int64)),
            collisions=Array.of(np.zeros((ticks, 1), np.int64)),
            food=Array.of(np.zeros((ticks, 1), np.int64)),
            changes=Array.of(np.zeros((0, 5), np.int64)),
            final=True,
        )
    )
    recorder.close()
    rec.flush()
    rec.disconnect()
    trail = read(tmp_path / "trail.rrd")["/world/trail/agent0"]
    pieces = dict(zip(trail["tick"], (len(strips) for strips in trail["LineStrips2D:strips"])))
    assert pieces == {0: 0, 50: 1, 100: 1, 150: 2}  # tick 0: one position, no line yet


@pytest.mark.parametrize(
    ("first", "bins", "said"),
    [
        (0, [999, 1999, 2999], None),
        (500, [999, 1999, 2999], "recording starts at tick 500: the recorder started late"),  # its map of tick 0
        (8000, [9999, 10999], "the run resumed at tick 8000: this recording holds it from there"),  # its map of 8000
    ],
)
def test_a_recording_begun_mid_run_says_why_and_draws_only_the_bins_whose_start_it_knows(tmp_path, first, bins, said):
    """The world counts collisions from the run's start (a resumed run's count goes on from its
    checkpoint): a bin's are the count at its end less the count at its start, 0 for the run's
    first bin. A recording that begins after both (a resumed part) leaves out its first bin rather
    than draw the whole run's collisions in it. The world's map names the tick its data begin at:
    0, or where a run resumed; a recording that starts later started late."""
    import rerun as rr

    from services.bus.schemas import Array, WorldMap, WorldState, new_run_id
    from services.recorder.recorder import Recorder

    params, run, ticks = params_for("paper"), new_run_id(), np.arange(first, first + 3000)
    collisions = ((ticks + 1) // 100)[:, None]  # one collision every 100 ticks: 10 in each bin of 1,000
    rec = rr.RecordingStream("spikinglab-test", recording_id="curve")
    rec.save(str(tmp_path / "curve.rrd"))
    recorder = Recorder(rec)
    grid = generate_map(params, 0)[None]
    map_tick = 0 if first < 1000 else first
    recorder.on(WorldMap(tick=map_tick, run=run, grid=Array.of(grid), x_min=params.x_min, y_min=params.y_min))
    arrays = {
        "sensors": np.full((len(ticks), 1, len(SENSORS)), np.nan),
        "pos": np.full((len(ticks), 1, 2), 50.0),
        "heading": np.zeros((len(ticks), 1)),
        "events": np.zeros((len(ticks), 1, 4), np.int64),
        "collisions": collisions,
        "food": np.zeros((len(ticks), 1), np.int64),
    }
    for lo in range(0, len(ticks), 700):  # batches that do not end at a bin's end
        part = {name: values[lo : lo + 700] for name, values in arrays.items()}
        final = lo + 700 >= len(ticks)
        recorder.on(WorldState.of(part, [], tick=int(ticks[lo]), run=run, sensor_names=SENSORS, final=final))
    recorder.close()
    rec.flush()
    rec.disconnect()
    data = read(tmp_path / "curve.rrd")
    curve = data["/learning/collisions_per_1000"]
    assert list(curve["tick"]) == bins
    assert [v[0] for v in curve["Scalars:scalars"]] == [10.0] * len(bins)
    texts = [t[0] for t in data["/events"]["TextLog:text"]]
    about_start = [t for t in texts if "started late" in t or "resumed" in t]
    assert about_start == ([said] if said else [])


def test_a_recorder_keeps_an_earlier_recording_at_its_out_until_it_has_its_own(tmp_path):
    """A launch file's fixed --out: the run that follows may end before its first tick (refused by
    a shard, say); the earlier recording is kept as recording.previous.rrd, never emptied."""
    out = write_recording(tmp_path / "recording.rrd", ticks=10)
    earlier = out.read_bytes()
    recorder = start("record", "--listen", endpoint(tmp_path, "rec"), "--out", out, log=tmp_path / "recorder.log")
    try:
        wait_for(lambda: "recording group" in (tmp_path / "recorder.log").read_text(), 60, "the recorder to start")
        recorder.send_signal(signal.SIGINT)
        finish(recorder, 30, tmp_path / "recorder.log")
    finally:
        recorder.kill()
    assert (tmp_path / "recording.previous.rrd").read_bytes() == earlier
    assert out.exists() and out.read_bytes() != earlier
    log = (tmp_path / "recorder.log").read_text()
    assert f"{out} held an earlier recording: kept as {tmp_path / 'recording.previous.rrd'}" in log
    assert "no state came: a recording holds what the world and the brain publish with --publish-state" in log


def write_recording(path, ticks):
    """A small Rerun recording: a value at each tick 0 .. ticks - 1."""
    import rerun as rr

    rec = rr.RecordingStream("spikinglab-test", recording_id=path.stem)
    rec.save(str(path))
    for tick in range(ticks):
        rec.set_time("tick", sequence=tick)
        rec.log("/value", rr.Scalars([float(tick)]))
    rec.flush()
    rec.disconnect()
    return path


def spikinglab(*args) -> subprocess.CompletedProcess:
    """A spikinglab command run to its end."""
    command = [sys.executable, "-m", "spikinglab", *map(str, args)]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)


def screenshot_of(*args, env=None) -> subprocess.CompletedProcess:
    """`spikinglab screenshot ARGS` where no Vulkan driver is needed: it refuses before its viewer
    starts, or the viewer is denied one. (Spelt so that conftest does not mark the tests that use
    it as needing a driver and skip them where there is none.)"""
    command = [sys.executable, "-m", "spikinglab", "screenshot"] + [str(a) for a in args]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120, env=env)


@pytest.mark.parametrize("name", ["weights.npz", "summary.json"])
def test_record_refuses_an_out_that_is_not_a_recording_and_leaves_it_alone(tmp_path, name):
    """A user's file given as --out was moved aside, and by a second run deleted."""
    out = tmp_path / name
    out.write_bytes(b"the user's own file")
    for _ in range(2):
        done = spikinglab("record", "--out", out)
        assert done.returncode == 2
        assert done.stderr == (
            f"spikinglab record: argument --out: {out} is not a Rerun recording (.rrd): refusing to replace it "
            "(see spikinglab record --help)\n"
        )
    assert out.read_bytes() == b"the user's own file" and sorted(tmp_path.iterdir()) == [out]


@pytest.mark.parametrize(
    "options, said",
    [
        (["--grpc-host", "127.0.0.1"], "argument --grpc-host: only with --serve or --web"),
        (["--grpc-port", "9000"], "argument --grpc-port: only with --serve or --web"),
        (["--serve", "--web-port", "9000"], "argument --web-port: only with --web"),
        (["--nice", "100"], "argument --nice: must be at most 19 (the range of a process's niceness), got 100"),
        (["--nice", "-21"], "argument --nice: must be at least -20, got -21"),
    ],
)
def test_record_refuses_options_it_would_ignore_or_change(tmp_path, options, said):
    done = spikinglab("record", *options, "--out", tmp_path / "rec.rrd")
    assert done.returncode == 2 and done.stderr == f"spikinglab record: {said} (see spikinglab record --help)\n"
    assert not (tmp_path / "rec.rrd").exists()


def test_the_live_views_options_take_their_defaults_where_they_serve():
    from services.recorder.service import parser

    web = parser().parse_args(["--web"])
    assert (web.grpc_host, web.grpc_port, web.web_port) == ("0.0.0.0", 9876, 9090)
    served = parser().parse_args(["--serve", "--grpc-host", "127.0.0.1", "--grpc-port", "9000"])
    assert (served.grpc_host, served.grpc_port, served.web_port) == ("127.0.0.1", 9000, 9090)


def test_screenshot_names_a_recording_cut_short_as_damaged_in_one_line(tmp_path):
    whole = write_recording(tmp_path / "whole.rrd", ticks=500).read_bytes()
    half = tmp_path / "half.rrd"
    half.write_bytes(whole[: len(whole) // 2])  # as a writer killed mid-write leaves it
    done = screenshot_of(half)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr  # no RerunWarning
    assert done.stderr.startswith(f"spikinglab screenshot: {half}: a damaged Rerun recording, cut short")
    assert f"rerun rrd optimize {half} -o repaired.rrd" in done.stderr
    assert not (tmp_path / "replay.png").exists()


def test_screenshot_refuses_a_tick_beyond_the_recordings_last(tmp_path):
    recording = write_recording(tmp_path / "r.rrd", ticks=500)
    done = screenshot_of(recording, "--tick", 500)
    assert done.returncode == 2
    assert done.stderr == (
        "spikinglab screenshot: argument --tick: 500 is beyond the recording's last tick, 499 "
        "(see spikinglab screenshot --help)\n"
    )
    (tmp_path / "run").mkdir()
    first = write_recording(tmp_path / "run" / "recording.rrd", ticks=500)  # a resumed run's parts
    for part_start in (400, 600):
        (tmp_path / "run" / f"recording-from-tick{part_start}.rrd").write_bytes(b"")
    done = screenshot_of(first, "--tick", 700)
    assert done.returncode == 2 and done.stderr.startswith(
        "spikinglab screenshot: argument --tick: 700 is beyond the recording's last tick, 499; "
        f"{tmp_path / 'run' / 'recording-from-tick600.rrd'}, a later part of the run, holds it"
    )


def test_screenshot_without_a_graphics_driver_says_what_to_install_in_one_line(tmp_path):
    """The Vulkan loader is given no driver (and wgpu no other backend), so that this holds on a
    machine with one too: the viewer finds nothing to render with, as on one without."""
    recording = write_recording(tmp_path / "r.rrd", ticks=10)
    nowhere = str(tmp_path / "no-driver.json")
    env = {**os.environ, "WGPU_BACKEND": "vulkan", "VK_ICD_FILENAMES": nowhere, "VK_DRIVER_FILES": nowhere}
    before = headless_viewers()
    done = screenshot_of(recording, "--out", tmp_path / "r.png", env=env)
    assert done.returncode == 1
    assert done.stderr == (
        "spikinglab screenshot: the headless viewer found no graphics driver to render with: it needs Vulkan, "
        "and without a GPU Mesa's software driver (Debian: apt-get install mesa-vulkan-drivers libvulkan1)\n"
    )
    assert headless_viewers() == before and not (tmp_path / "r.png").exists()


def test_a_viewer_that_stopped_otherwise_is_told_by_its_last_whole_lines_without_the_backtrace():
    from services.recorder.screenshot import why_it_stopped

    stderr = (
        "\x1b[2m2026-11-27T09:18:42Z\x1b[0m \x1b[32m INFO\x1b[0m re_grpc_server: Listening for gRPC connections\n"
        "\n"
        "thread 'main' panicked at 'index out of bounds: the len is 3 but the index is 7'\n"
        "re_viewer/src/app/mod.rs:1425\n"
        "stack backtrace:\n"
        "   6: core::panicking::panic_fmt\n"
        "  22: __libc_start_call_main\n"
        "             at libc_start_call_main.h:58:16\n"
        "\n"
        "Troubleshooting Rerun: https://www.rerun.io/docs/overview/installing-rerun/troubleshooting\n"
        "Report bugs: https://github.com/rerun-io/rerun/issues\n"
    )
    assert why_it_stopped("x" * 5000 + "\n" + stderr).splitlines() == [
        "the headless viewer stopped:",
        "xxxxxxxxxx" * 500,  # a line is kept whole or left out, never cut
        "2026-11-27T09:18:42Z  INFO re_grpc_server: Listening for gRPC connections",
        "thread 'main' panicked at 'index out of bounds: the len is 3 but the index is 7'",
        "re_viewer/src/app/mod.rs:1425",
    ]
