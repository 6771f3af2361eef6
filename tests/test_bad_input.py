"""Bad input, one row per case, as a user meets it: the exit code (2: usage, 1: at run time), one
line naming what was wrong, no traceback, nothing left running, no run folder with a result."""

import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from services.brain.checkpoint import save_weights
from services.brain.circuit import load_circuit
from services.brain.engine import Engine
from spikinglab import cli

from .processes import endpoint, running_with, start, wait_for


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("inputs")
    circuit = load_circuit("insect")
    save_weights(folder / "good.npz", Engine(circuit), circuit)
    data = (folder / "good.npz").read_bytes()
    (folder / "truncated.npz").write_bytes(data[: len(data) // 2])
    np.savez(folder / "foreign.npz", x=np.arange(3))
    (folder / "nostart.txt").write_text("#####\n#...#\n#####\n")
    (folder / "not.rrd").write_text("not a recording\n")
    (folder / "typo.toml").write_text("[world]\ntick = 2000\n")
    (folder / "badvalue.toml").write_text("[world]\nticks = 0\n")
    (folder / "manyshards.toml").write_text('[world]\nagents = 2\nshard = "1/3"\n')
    (folder / "noservice.toml").write_text("[mind]\nonce = true\n")
    (folder / "broken.toml").write_text("[world\nticks = 2000\n")
    (folder / "broken.json5").write_text('{mode: "client",, }\n')
    (folder / "badmode.json5").write_text('{mode: "boss"}\n')
    (folder / "list.json5").write_text('["tls/127.0.0.1:7447"]\n')
    (folder / "occupied").write_text("a file, not a folder\n")
    (folder / "soak" / "brain.json").mkdir(parents=True)  # where the soak's brain writes its stats
    save_weights(folder / "two.npz", Engine(circuit, agents=2), circuit)
    save_weights(folder / "large.npz", Engine(circuit).get_weights() * 10, circuit)
    save_weights(folder / "double.npz", Engine(circuit).get_weights() * 2, circuit)
    save_weights(folder / "nan.npz", Engine(circuit).get_weights() * np.nan, circuit)
    (folder / "low-wmax.csv").write_text("w_max\n6\n")
    (folder / "sweeps" / "done").mkdir(parents=True)
    (folder / "sweeps" / "done" / "table.md").write_text("an earlier sweep's table\n")
    (folder / "list.toml").write_text("[world]\nticks = [1000, 2000]\n")
    (folder / "word.toml").write_text('[world]\npublish_state = "yes"\n')
    (folder / "false.toml").write_text("[world]\nticks = false\n")
    (folder / "escape.toml").write_text('[world]\n[brain]\n["../escape"]\nservice = "record"\n')
    (folder / "nomap.toml").write_text(f'[world]\nmap = "{folder / "none.txt"}"\n[brain]\n')
    (folder / "bigobjects.toml").write_text('[gateway]\nbackend = "sim"\nsim_object_cm = 100\n[brain]\nclock = 50\n')
    (folder / "unfit-circuit.toml").write_text('[world]\nticks = 500\n[brain]\ncircuit = "conditioning"\n')
    (folder / "edited" / "command.json").parent.mkdir()
    (folder / "edited" / "command.json").write_text('{"argv": ["--ticks", "zz"]}')  # a run's options, edited by hand
    (folder / "help.toml").write_text("[world]\nhelp = true\n")
    (folder / "until-list.toml").write_text('[launch]\nuntil = ["world"]\n[world]\nticks = 1000\n')
    (folder / "typo.csv").write_text("a_plsu,w_max\n0.02,15\n")
    (folder / "rows.csv").write_text("a_plus\n0.01\n0.02\n0.03\n")
    (folder / "word.csv").write_text("a_plus,move_step\n0.02,1\n0.02,fast\n")
    (folder / "low.csv").write_text("w_max\n3\n")
    (folder / "negative.csv").write_text("a_plus\n0.02\n-0.02\n")
    unfit = {"rows": f'params = "{folder / "rows.csv"}"', "shards": 'shard = "2/2"', "group": 'group = "other"'}
    for name, brain in unfit.items():  # a brain each that could never serve its world: refused before anything starts
        (folder / f"unfit-{name}.toml").write_text(f"[world]\nagents = 2\n[brain]\nonce = true\n{brain}\n")
    world_rows = f'[world]\nagents = 2\nparams = "{folder / "rows.csv"}"\n[brain]\nonce = true\n'
    (folder / "world-rows.toml").write_text(world_rows)  # the world's own file does not fit it
    (folder / "load-missing.toml").write_text(
        f'[brain]\nconnect = ["tcp/127.0.0.1:7447"]\nload = "{folder / "missing.npz"}"\n'
    )
    (folder / "unfit-noshard.toml").write_text("[world]\nagents = 2\nshards = 2\n[brain]\nonce = true\n")
    (folder / "unfit-pieces.toml").write_text(  # two world shards, a brain that serves one world's agents
        '[world-1]\nservice = "world"\nagents = 2\nshard = "1/2"\n'
        '[world-2]\nservice = "world"\nagents = 2\nshard = "2/2"\n[brain]\nonce = true\n'
    )
    shard = '[world-{}]\nservice = "world"\nagents = 4\nticks = {}\nshard = "{}/2"\n'
    (folder / "shards-differ.toml").write_text(shard.format(1, 500, 1) + shard.format(2, 700, 2))
    (folder / "shard-twice.toml").write_text(shard.format(1, 500, 1) + shard.format(2, 500, 1))
    (folder / "bad.toml").write_text(
        '[neurons]\nA = "regular"\n[[synapses]]\nfrom = "A"\nto = "B"\nweight = 5\ndelay = 1\n'
    )
    return folder


@pytest.fixture(scope="module")
def busy_port():
    """A port that this test listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


@pytest.fixture(scope="module")
def closed_port():
    """A port where nothing listens (a connection is refused): this test holds it bound without
    listening, so that no other process can take it meanwhile."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


# usage errors found by the parser (argparse) or the command line's front, before anything starts:
# id, arguments ({f}: the input files), exit code, what the one line says; run in-process
ARGUMENTS = [
    ("run ticks below one bin", "run --ticks 500", 2, "argument --ticks: must be at least 1,000, got 500"),
    ("run agents 0", "run --agents 0", 2, "argument --agents: must be at least 1, got 0"),
    ("run negative A", "run --a-plus -0.1", 2, "argument --a-plus: must be a number above 0, got -0.1"),
    ("run learning rate not learning", "run --no-training --a-plus 0.05", 2, "argument --a-plus: a learning rate, but"),
    ("brain learning rate not learning", "brain --no-training --a-plus 0.05", 2, "but --no-training keeps the weights"),
    (
        "sharded brain for the recorder",
        "brain --shard 1/2 --publish-state",
        2,
        "argument --shard: got '1/2' with --publish-state: a sharded brain serves a world in lock-step and does not "
        "publish its state",
    ),
    (
        "sharded world's brain keeping checkpoints",
        "brain --world-shards 2 --checkpoint {f}/ck",
        2,
        "argument --world-shards: got 2 with --checkpoint: a sharded world's brain keeps no checkpoints, runs no robot "
        "and publishes no state: drop --checkpoint",
    ),
    ("run detail not agents", "run --detail x", 2, "argument --detail: expected agent numbers separated by commas"),
    ("run abbreviated option", "run --tick 5", 2, "unrecognized arguments: --tick 5"),
    (
        "run stream order without its seed",
        "run --order netlogo-stream",
        2,
        "order netlogo-stream draws from NetLogo's stream as the source's setup leaves it: it needs",
    ),
    ("sweep 500 ticks", "sweep --ticks 500", 2, "argument --ticks: must be at least 1,000, got 500"),
    ("sweep no seeds", "sweep --seeds 0", 2, "argument --seeds: must be at least 1, got 0"),
    ("sweep a value twice", "sweep --a-plus 0.02 0.03 0.02", 2, "argument --a-plus: 0.02 given twice"),
    ("conditioning no trials", "conditioning --trials 0", 2, "argument --trials: must be at least 1, got 0"),
    ("screenshot window size", "screenshot {f}/not.rrd --size big", 2, "argument --size: expected WIDTHxHEIGHT"),
    ("run negative seed", "run --seed -1", 2, "argument --seed: must be at least 0, got -1"),
    ("brain negative clock", "brain --clock -5", 2, "argument --clock: must be 0 or more, got -5"),
    ("brain clock not a number", "brain --clock nan", 2, "argument --clock: expected a finite number, got nan"),
    (
        "gateway spin of 0 ms (the brick's 'until stopped')",
        "gateway --spin-ms 0",
        2,
        "argument --spin-ms: must be at least 1, got 0",
    ),
    (
        "gateway command age below 0",
        "gateway --max-command-age -1",
        2,
        "argument --max-command-age: must be a number above 0, got -1",
    ),
    ("record flushing every 0 ticks", "record --flush-every 0", 2, "argument --flush-every: must be at least 1, got 0"),
    ("bench loop no repeats", "bench loop --repeats 0", 2, "argument --repeats: must be at least 1, got 0"),
    ("record viewer not a URL", "record --viewer nothing", 2, "argument --viewer: 'nothing' is not a viewer URL"),
    (
        "malformed endpoint",
        "brain --connect localhost:7447",
        2,
        "argument --connect: 'localhost:7447' is not an endpoint",
    ),
    ("endpoint without port", "world --listen tcp/127.0.0.1", 2, "a tcp endpoint needs host:port"),
    ("router given a group (it routes every group)", "router --group g", 2, "unrecognized arguments: --group g"),
    (
        "brain shard beyond its count",
        "brain --shard 4/3",
        2,
        "argument --shard: must be I/N with 1 <= I <= N (e.g. 2/3), got '4/3'",
    ),
    (  # argparse took -1/2 for an option: "expected one argument"
        "world shard written with a minus",
        "world --shard -1/2",
        2,
        "argument --shard: its value '-1/2' begins with '-', so write --shard=-1/2",
    ),
    ("world shard of no shards", "world --shard 1/0", 2, "argument --shard: must be I/N with 1 <= I <= N"),
    ("world shard not I/N", "world --shard 2of3", 2, "argument --shard: must be I/N with 1 <= I <= N"),
    (
        "more world shards than agents",
        "world --shard 1/9 --agents 4",
        2,
        "argument --shard: 9 world shards of 4 agents (--agents), got '1/9': at most one shard per agent",
    ),
    (
        "more brain shards than agents",
        "world --shards 3 --agents 2",
        2,
        "argument --shards: 3 brain shards of 2 agents (--agents): at most one shard per agent",
    ),
    (
        "world shard of a shared arena",
        "world --shard 1/2 --agents 4 --shared",
        2,
        "argument --shard: got '1/2' with --shared: the insects of a shared arena meet",
    ),
    (
        "world shard with checkpoints",
        "world --shard 1/2 --agents 4 --checkpoint kept",
        2,
        "argument --shard: got '1/2' with --checkpoint: a sharded world keeps no checkpoints",
    ),
    (
        "zenoh config missing",
        "world --zenoh-config certs/world.json5",
        2,
        "argument --zenoh-config: cannot read certs/world.json5: No such file or directory (`spikinglab certs DIR`",
    ),
    ("zenoh config not JSON5", "brain --zenoh-config {f}/broken.json5", 2, "broken.json5 is not a JSON5 config"),
    ("zenoh config not an object", "brain --zenoh-config {f}/list.json5", 2, "should hold one JSON5 object"),
    ("unknown command", "fly", 2, "unknown command 'fly'"),
    ("unknown benchmark", "bench fly", 2, "no benchmark 'fly' (one of engine,"),
    ("run detail of no agent", "run --detail ,", 2, "argument --detail: name at least one agent"),
    ("run detail beyond the agents", "run --agents 2 --detail 0,5", 2, "argument --detail: agent 5 of 2"),
    ("run id a path", "run --id ../elsewhere", 2, "argument --id: expected a folder name, not a path"),
    (
        "sweep over an earlier sweep",
        "sweep --runs {f}/sweeps --id done",
        2,
        "argument --id: {f}/sweeps/done holds a sweep already: choose another --id",
    ),
    (
        "world out where a file is",
        "world --out {f}/occupied",
        2,
        "argument --out: cannot write to the folder {f}/occupied: {f}/occupied is a file, not a folder",
    ),
    (
        "brain save where nothing can be made",
        "brain --save /proc/none/w.npz",
        2,
        "argument --save: cannot write /proc/none/w.npz: nothing can be written in /proc",
    ),
    ("gateway stats in a file", "gateway --stats {f}/occupied/g.json", 2, "argument --stats: cannot write"),
    ("record out a folder", "record --out {f}", 2, "argument --out: {f} is a folder; expected a file name"),
    ("launch logs in a file", "launch --logs {f}/occupied simulation", 2, "argument --logs: cannot write to the"),
    (
        "brain stream order without its seed",
        "brain --order netlogo-stream",
        2,
        "order netlogo-stream draws from NetLogo's stream as the source's setup leaves it: it needs",
    ),
    (
        "world seed beyond a Java int",
        "world --netlogo-seed 99999999999",
        2,
        "must be at most 2,147,483,647 (a Java int)",
    ),
    ("world group of two segments", "world --group a/b", 2, "argument --group: group name 'a/b' must be one key"),
    ("brain on CPU -1", "brain --cpu -1", 2, "argument --cpu: must be at least 0, got -1"),
    ("brain on a CPU not here", "brain --cpu 4096", 2, "argument --cpu: CPU 4096 is not one this process may use"),
    ("record serving on no address", "record --serve --grpc-host 999.1.1.1", 2, "'999.1.1.1' is not an IP address"),
    ("gateway speed beyond 100", "gateway --speed 500", 2, "--speed must be within -100..100, got 500"),
    ("gateway Bluetooth without its brick", "gateway --protocol Bluetooth", 2, "--protocol Bluetooth needs --host"),
    (
        "fake brick seeing beyond its sensor",
        "fake-brick --distance-cm 1e9",
        2,
        "argument --distance-cm: must be 0 .. 255",
    ),
    ("fake brick reporting every 0 s", "fake-brick --report-every 0", 2, "argument --report-every: must be a number"),
    ("certs for no host name", "certs c --host bad!name", 2, "argument --host: expected an IP address or a host"),
    ("launch file missing", "launch {f}/none.toml", 2, "no launch file"),
    ("bench gpu order of phased", "bench gpu --semantics phased --order file", 2, "the phased semantics has none"),
    (
        "bench robot bin beyond a run",
        "bench robot --seconds 1 --bin 10",
        2,
        "argument --bin: 10 s is longer than a run",
    ),
    (
        "bench scale links with shards",
        "bench scale --links --world-shards 2",
        2,
        "argument --world-shards: not with --links",
    ),
    ("bench soak robot for ticks", "bench soak --robot --ticks 20000", 2, "argument --ticks: not with --robot"),
    ("bench soak lock-step for seconds", "bench soak --clock 500", 2, "argument --clock: only with --robot"),
    ("bench engine insects of no evaluate", "bench engine --insects 64", 2, "argument --insects: only with --evaluate"),
    (
        "bench engine agents of evaluate",
        "bench engine --evaluate --agents 64",
        2,
        "argument --agents: not with --evaluate",
    ),
    ("bench engine rounds of calls", "bench engine --calls --rounds 3", 2, "argument --rounds: not with --calls"),
    (
        "bench engine two cases alone",
        "bench engine --calls --evaluate",
        2,
        "argument --evaluate: not allowed with argument --calls",
    ),
]
# what only a process shows (a run's validation, a port in use, Zenoh's word): id, arguments ({f}: the
# input files, {busy}: a port in use, {closed}: a port where nothing listens), exit code, the one line
CASES = [
    (
        "bench soak with a process that cannot start",  # its wait for the run held the bench for good
        "bench soak --ticks 10000 --out {f}/soak",
        1,
        "the brain ended before the run started (exit 2)",
    ),
    (
        "run circuit for another body",
        "run --circuit conditioning",
        2,
        "circuit 'conditioning' binds sensors ['c', 'u'] that the world does not publish",
    ),
    ("run broken circuit file", "run --circuit {f}/bad.toml", 2, "synapses[0] (A -> B): to: unknown neuron 'B'"),
    (
        "run truncated checkpoint",
        "run --load {f}/truncated.npz",
        2,
        "truncated.npz: not a weights file (not an .npz archive: truncated, or another kind of file",
    ),
    (
        "run foreign npz",
        "run --load {f}/foreign.npz",
        2,
        "foreign.npz: not a weights file (an .npz without the arrays weights and synapses",
    ),
    ("run missing checkpoint", "run --load {f}/missing.npz", 2, "missing.npz: cannot read it (No such file"),
    ("run map without start", "run --map {f}/nostart.txt", 2, "nostart.txt: no start 'S' in the map"),
    (
        "run params unknown column",
        "run --params {f}/typo.csv",
        2,
        "typo.csv: unknown per-agent parameter 'a_plsu' (known: a_plus, ",
    ),
    (
        "run params rows not agents",
        "run --agents 2 --params {f}/rows.csv",
        2,
        "rows.csv: 3 rows of values for 2 agents (--agents): give one row for all of them, or one per agent",
    ),
    (
        "run params not a number",
        "run --agents 2 --params {f}/word.csv",
        2,
        "word.csv, line 3: move_step is 'fast', not a number",
    ),
    (
        "run params out of range",
        "run --agents 2 --params {f}/negative.csv",
        2,
        "negative.csv, line 3: per-agent parameter a_plus: agent 1 has -0.02, it must be a finite number >= 0",
    ),
    (
        "brain params the circuit refuses",
        "brain --params {f}/low.csv",
        2,
        "low.csv, line 2: the values of agent 0 (w_max 3) do not fit circuit 'insect': BLACK->PAIN: weight 5.0",
    ),
    (
        "run params and --a-plus both set A+",  # the file's would win, and the run's first line say --a-plus's
        "run --agents 3 --params {f}/rows.csv --a-plus 0.03",
        2,
        "argument --a-plus: sets A+ and A- of every agent, and parameter file {f}/rows.csv sets a_plus per agent: "
        "give one of them",
    ),
    (
        "brain params and --a-plus both set A+",
        "brain --params {f}/rows.csv --a-plus 0.03",
        2,
        "parameter file {f}/rows.csv sets a_plus per agent: give one of them",
    ),
    ("world params missing", "world --params {f}/none.csv", 2, "none.csv: cannot read it (No such file or directory)"),
    ("screenshot of a text file", "screenshot {f}/not.rrd", 2, "not.rrd: not a Rerun recording (.rrd)"),
    ("screenshot of nothing", "screenshot {f}/none.rrd", 2, "none.rrd: no such recording"),
    ("screenshot of a folder", "screenshot {f}/sweeps", 2, "sweeps: a folder; expected a recording (.rrd)"),
    ("screenshot to a text file", "screenshot {f}/not.rrd --out {f}/shot.txt", 2, "shot.txt: a screenshot is a PNG"),
    ("screenshot of a text file at a tick", "screenshot {f}/not.rrd --tick 5", 2, "not.rrd: not a Rerun recording"),
    (
        "record viewer where none runs",
        "record --viewer rerun+http://127.0.0.1:{closed}/proxy --out {f}/r.rrd",
        1,
        "no viewer answers at rerun+http://127.0.0.1:{closed}/proxy",
    ),
    ("port in use", "brain --listen tcp/127.0.0.1:{busy}", 1, "Address already in use (os error 98)]"),  # no .rs
    ("zenoh config Zenoh refuses", "brain --zenoh-config {f}/badmode.json5", 1, "badmode.json5: "),
    ("certs where a file is", "certs {f}/occupied", 2, "occupied is a file, not a folder for the certificates"),
    ("launch file not TOML", "launch {f}/broken.toml", 2, "broken.toml is not valid TOML"),
    ("launch file misspelt option", "launch {f}/typo.toml", 2, "typo.toml, [world]: unrecognized arguments: --tick"),
    (
        "launch file bad value",
        "launch {f}/badvalue.toml",
        2,
        "badvalue.toml, [world]: argument --ticks: must be at least 1, got 0",
    ),
    (
        "launch more world shards than agents",
        "launch {f}/manyshards.toml",
        2,
        "manyshards.toml, [world]: argument --shard: 3 world shards of 2 agents (--agents), got '1/3'",
    ),
    (
        "launch brain params for other agents",
        "launch {f}/unfit-rows.toml",
        2,
        "unfit-rows.toml, [brain]: parameter file {f}/rows.csv: 3 rows of values for 2 agents (agents of [world])",
    ),
    (
        "launch world params for other agents",
        "launch {f}/world-rows.toml",
        2,
        "world-rows.toml, [world]: parameter file {f}/rows.csv: 3 rows of values for 2 agents (agents = 2)",
    ),
    (
        "launch brain shards unlike the world's",
        "launch {f}/unfit-shards.toml",
        2,
        'unfit-shards.toml, [brain]: shard = "2/2", but [world] runs the brain as shards = 1',
    ),
    (
        "launch brain weights missing",
        "launch {f}/load-missing.toml",
        2,
        "load-missing.toml, [brain]: {f}/missing.npz: cannot read it (No such file or directory)",
    ),
    (
        "launch brain without shard, the world's shards",
        "launch {f}/unfit-noshard.toml",
        2,
        'unfit-noshard.toml, [brain]: no shard (so "1/1"), but [world] runs the brain as shards = 2',
    ),
    (
        "launch brain for one world of world shards",
        "launch {f}/unfit-pieces.toml",
        2,
        "unfit-pieces.toml, [brain]: world_shards = 1, but [world-1] is one of 2 world shards: set world_shards = 2",
    ),
    (
        "launch file's world shards of two populations",
        "launch {f}/shards-differ.toml",
        2,
        "shards-differ.toml, [world-2]: not of world shard 1's population: --ticks 700 here, 500 at world shard 1",
    ),
    (
        "launch file's world shard twice",
        "launch {f}/shard-twice.toml",
        2,
        'shard-twice.toml, [world-2]: shard = "1/2" is also [world-1]\'s: each shard is one process',
    ),
    (
        "launch brain in another group",
        "launch {f}/unfit-group.toml",
        2,
        "unfit-group.toml, [brain]: group 'other' is no world's in this file",
    ),
    ("launch file unknown service", "launch {f}/noservice.toml", 2, "noservice.toml, [mind]: unknown service 'mind'"),
    ("launch file list for one value", "launch {f}/list.toml", 2, "[world]: ticks = [1000, 2000]: takes one value"),
    ("launch file switch given a word", "launch {f}/word.toml", 2, "[world]: publish_state = 'yes': a switch"),
    (
        "launch brain of a circuit for another body",
        "launch {f}/unfit-circuit.toml",
        2,
        "unfit-circuit.toml, [brain]: circuit 'conditioning' binds sensors ['c', 'u'] that the world does not publish",
    ),
    ("run detail of no recording", "run --no-record --detail 0", 2, "argument --detail: says what the recording"),
    ("brain stale readings in lock-step", "brain --stale-after 2", 2, "argument --stale-after: only with --clock"),
    (
        "brain checkpoint of a robot",
        "brain --clock 1000 --checkpoint {f}",
        2,
        "argument --checkpoint: not with --clock",
    ),
    ("launch file value given false", "launch {f}/false.toml", 2, "[world]: ticks = false: takes a value"),
    ("launch file asks for help", "launch {f}/help.toml", 2, "[world]: help: not an option of a process"),
    (
        "launch file until a list",
        "launch {f}/until-list.toml",
        2,
        "[launch]: until = ['world'] is not one of its processes (world)",
    ),
    ("launch list and a file", "launch --list simulation", 2, "argument --list: names the shipped launch files"),
    ("launch name a path", "launch {f}/escape.toml", 2, "escape.toml: ['../escape']: a process's name is letters"),
    ("launch world map missing", "launch {f}/nomap.toml", 2, "none.txt: cannot read map file"),
    ("launch sim objects too big", "launch {f}/bigobjects.toml", 2, "[gateway]: the objects (100.0 cm) must fit their"),
    (
        "run resumed with options edited",
        "run --resume {f}/edited",
        2,
        "edited/command.json holds options this run refuses: argument --ticks: expected a whole number, got 'zz'",
    ),
    ("run weights of other agents", "run --load {f}/two.npz", 2, "two.npz: weights of 2 agents, the run has 1"),
    ("run weights not numbers", "run --load {f}/nan.npz", 2, "nan.npz: weights must be finite numbers > 0"),
    (
        "run weights out of range",
        "run --load {f}/large.npz",
        2,
        "large.npz: weight 50.0 of plastic synapse BLACK->PAIN of agent 0 outside [1.0, 15.0]",
    ),
    (
        "run weights above a params file's w_max",  # the brain would stop at its start with the others running
        "run --load {f}/double.npz --params {f}/low-wmax.csv",
        2,
        "double.npz: weight 10.0 of plastic synapse BLACK->PAIN of agent 0 outside [1.0, 6.0] (w_max of the --params",
    ),
    ("run circuit not text", "run --circuit {f}/two.npz", 2, "two.npz: not a circuit file (not text"),
]


def arguments(command: str, tmp_path, **places) -> list[str]:
    """The row's command line, its outputs in tmp_path."""
    argv = command.format(**places).split()
    if argv[0] in ("run", "sweep") and "--runs" not in argv and "--resume" not in argv:  # a resumed run's folder
        argv += ["--runs", str(tmp_path / "runs")]
    elif argv[0] == "conditioning":
        argv += ["--out", str(tmp_path / "figures")]
    return argv


def ended_saying(exit_code, out: str, err: str, code: int, says: str, tmp_path) -> None:
    """A command ended as a user must meet bad input: exit code `code`, its last line on stderr
    saying `says`, no traceback, no result in tmp_path and nothing of it left running."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert exit_code == code, err
    assert lines and says in lines[-1], err
    assert "Traceback" not in err + out
    assert not list(tmp_path.rglob("summary.json")) and not list(tmp_path.rglob("*.png"))
    assert not running_with(str(tmp_path))


@pytest.fixture
def same_environment():
    """The commands' start sets variables for their process (OpenMP's); this process gets its own back."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)


@pytest.mark.parametrize("case, command, code, says", ARGUMENTS, ids=[c[0] for c in ARGUMENTS])
def test_bad_arguments(case, command, code, says, files, tmp_path, monkeypatch, capsys, same_environment):
    """In this process: spikinglab's main with the row's arguments ends as the process would."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as ended:
        cli.main(arguments(command, tmp_path, f=files))
    out, err = capsys.readouterr()
    ended_saying(ended.value.code, out, err, code, says.format(f=files), tmp_path)


@pytest.mark.parametrize("case, command, code, says", CASES, ids=[c[0] for c in CASES])
def test_bad_input(case, command, code, says, files, busy_port, closed_port, tmp_path):
    places = {"f": files, "busy": busy_port, "closed": closed_port}
    done = subprocess.run(
        [sys.executable, "-m", "spikinglab", *arguments(command, tmp_path, **places)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    ended_saying(done.returncode, done.stdout, done.stderr, code, says.format(**places), tmp_path)


def test_connecting_where_nothing_answers_is_reported_within_10_s(closed_port, tmp_path):
    log = tmp_path / "brain.log"
    brain = start("brain", "--connect", f"tcp/127.0.0.1:{closed_port}", "--group", tmp_path.name, log=log)
    try:
        wait_for(lambda: "nothing answers" in log.read_text(), 15, "the brain to say so")
        assert f"nothing answers at tcp/127.0.0.1:{closed_port} after 10 s" in log.read_text()
        assert brain.poll() is None  # it goes on trying: the other side may start later
    finally:
        brain.terminate()
        brain.wait(10)


def test_a_service_with_no_endpoint_says_that_nothing_can_reach_it(tmp_path):
    log = tmp_path / "world.log"
    world = start("world", "--group", tmp_path.name, log=log)
    try:
        wait_for(lambda: "waiting for a brain" in log.read_text(), 60, "the world to wait for a brain")
        assert "WARNING no --connect and no --listen: no other process knows where to reach this one" in log.read_text()
    finally:
        world.terminate()
        world.wait(10)


def test_a_brain_that_refuses_every_reading_is_named_by_the_world(files, tmp_path):
    """Started by hand, a brain whose parameter file has 3 rows for the world's 2 agents refuses
    every sensors message and says why; the world waits for it (a brain may be fixed and
    restarted) and says, within 10 s, that it is on the bus but does not answer."""
    world_ep = endpoint(tmp_path, "world")
    world = start("world", "--listen", world_ep, "--agents", 2, "--group", tmp_path.name, log=tmp_path / "world.log")
    brain = start(
        "brain",
        "--connect",
        world_ep,
        "--group",
        tmp_path.name,
        "--params",
        files / "rows.csv",
        log=tmp_path / "brain.log",
    )
    try:
        world_log = tmp_path / "world.log"
        wait_for(lambda: "on the bus but no answer" in world_log.read_text(), 25, "the world to say so")
        said = "brain on the bus but no answer to tick 0 for 10 s: on a first run on this machine a brain compiles"
        assert said in world_log.read_text() and "else its log says why" in world_log.read_text()
        assert "does not fit the parameter file" in (tmp_path / "brain.log").read_text()
        assert world.poll() is None and brain.poll() is None  # neither gives up
    finally:
        for process in (world, brain):
            process.terminate()
            process.wait(10)
