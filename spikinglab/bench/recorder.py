"""Recorder benchmark: a one-agent lock-step run with and without the recorder.

Prints the loop's ticks/s both ways (pairs of runs in turns, the medians), the messages the
recorder took, its lag (how long after the world's last tick the file was complete) and the file
size. The last line is JSON.
Run: `spikinglab bench recorder` or `python -m spikinglab.bench.recorder`.
"""

from __future__ import annotations

import json
import re
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from services.bus.batching import state_batch
from services.launch import local_endpoints, spawn
from services.options import Parser, at_least
from spikinglab.bench import steady_rate


def one_run(ticks: int, record: bool, folder: Path) -> dict:
    (world_ep, brain_ep), sockets = local_endpoints("world", "brain")
    state = ["--publish-state"] if record else []
    with sockets:
        recorder = None
        if record:
            recorder = spawn(
                "record",
                ["--connect", world_ep, "--connect", brain_ep, "--out", folder / "recording.rrd"],
                folder / "recorder.log",
            )
        world = spawn(
            "world", ["--listen", world_ep, "--ticks", ticks, "--out", folder, "--cpu", 0] + state, subprocess.DEVNULL
        )
        brain = spawn(
            "brain", ["--listen", brain_ep, "--connect", world_ep, "--once", "--cpu", 1] + state, subprocess.DEVNULL
        )
        world.wait()
        world_done = time.monotonic()
        brain.wait(60)
        result = {"ticks_per_s": steady_rate(folder)}
        if recorder is not None:
            recorder.wait(300)
            result["lag_s"] = round(time.monotonic() - world_done, 2)
            line = (folder / "recorder.log").read_text()
            found = re.search(r"(\d+) messages in ([\d.]+) s, ([\d,.]+) messages/s", line)
            if found is None:
                raise SystemExit(f"the recorder did not say how many messages it took: {line[-500:]}")
            result["messages"], result["messages_per_s"] = int(found.group(1)), float(found.group(3).replace(",", ""))
            result["file_mb"] = round((folder / "recording.rrd").stat().st_size / 1e6, 2)
    return result


def alone(ticks: int) -> float:
    """Ticks/s the recorder decodes and writes when fed a run's state messages as fast as it takes them."""
    import rerun as rr

    from services.brain.circuit import load_circuit
    from services.brain.node import BrainNode, layout
    from services.bus.batching import TickBatch
    from services.bus.schemas import Array, Sensors, WorldMap, decode, encode, new_run_id
    from services.recorder.recorder import Recorder, blueprint
    from services.world.state import keep_state, state_message
    from services.world.world import SENSORS, World, world_actions

    circuit, world, run = load_circuit("insect"), World(seed=1), new_run_id()
    node = BrainNode(circuit)
    messages = [
        encode(
            WorldMap(tick=0, run=run, grid=Array.of(world.grid), x_min=world.params.x_min, y_min=world.params.y_min)
        ),
        encode(layout(circuit, 0, run)),
    ]
    batch, changes = TickBatch(state_batch(world.agents)), []
    values = world.sense()
    for t in range(ticks):
        answer = node.answer(Sensors(tick=t, names=SENSORS, values=Array.of(values), run=run))
        assert answer is not None, f"the brain did not answer tick {t}"  # each tick of the run it serves
        node.keep_state()
        world.act(world_actions(answer.names, answer.actions.numpy("actions", "|u1", 2)))
        keep_state(batch, changes, world, t, values)
        if batch.full or t + 1 == ticks:
            messages.append(encode(state_message(batch, changes, t + 1 == ticks, world, run)))
            messages.append(encode(node.state_message(final=t + 1 == ticks)))
        values = world.sense()
    with tempfile.TemporaryDirectory() as tmp:
        rec = rr.RecordingStream("bench", recording_id="bench")
        rec.save(str(Path(tmp) / "alone.rrd"), default_blueprint=blueprint(0))
        recorder = Recorder(rec)
        started = time.perf_counter()
        for payload in messages:
            recorder.on(decode(payload))
        recorder.close()
        rec.flush()
        return ticks / (time.perf_counter() - started)


def main(argv=None) -> dict:
    p = Parser(prog="spikinglab bench recorder", description=(__doc__ or "").splitlines()[0])
    p.add_argument("--ticks", type=at_least(2), default=30_000, help="ticks of each run (default 30000)")
    p.add_argument(
        "--repeats",
        type=at_least(1),
        default=3,
        help="pairs of runs, without and with the recorder in turns (default 3; medians reported)",
    )
    args = p.parse_args(argv)
    pairs = []  # in turns: this machine drifts more between minutes than the recording costs
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as a, tempfile.TemporaryDirectory() as b:
            pairs.append((one_run(args.ticks, False, Path(a)), one_run(args.ticks, True, Path(b))))
    plain = float(np.median([p["ticks_per_s"] for p, _ in pairs]))
    with_it = float(np.median([r["ticks_per_s"] for _, r in pairs]))
    costs = sorted(1 - r["ticks_per_s"] / p["ticks_per_s"] for p, r in pairs)
    recorded = pairs[-1][1]
    print(
        f"lock-step, 1 agent, {args.ticks:,} ticks, medians of {args.repeats} pairs in turns: {plain:,.0f} ticks/s "
        f"without the recorder, {with_it:,.0f} with it ({1 - with_it / plain:.0%} less; pair by pair: "
        f"{', '.join(f'{c:.0%}' for c in costs)})"
    )
    print(
        f"recorder: {recorded['messages']:,} messages (world and brain state in batches of {state_batch(1)} ticks), "
        f"file complete {recorded['lag_s']} s after the last tick, {recorded['file_mb']} MB (the last pair)"
    )
    result = {
        "loop_ticks_per_s": round(plain),
        "recorded_loop_ticks_per_s": round(with_it),
        "recording_cost_by_pair": [round(c, 3) for c in costs],
        "recorder_messages": recorded["messages"],
        "recorder_lag_s": recorded["lag_s"],
        "recording_mb": recorded["file_mb"],
    }
    capacity = alone(args.ticks)
    print(f"the recorder alone (decode, buffer, write {args.ticks:,} ticks fed at once): {capacity:,.0f} ticks/s")
    result["recorder_alone_ticks_per_s"] = round(capacity)
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
