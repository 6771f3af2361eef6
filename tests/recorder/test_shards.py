"""The recorder's join of world shards' state: their slices, in batches of their own, make the
population's state, as one world would have sent it; a slice that is not a shard's is refused."""

import msgspec
import numpy as np
import pytest
import rerun as rr

from services.bus.schemas import Array, BusError, WorldMap, WorldState, check_slice, decode, encode, new_run_id
from services.options import shard_slice
from services.recorder.recorder import Recorder
from services.recorder.shards import ShardJoin
from services.world.world import SENSORS, generate_map, params_for

from ..recordings import read

RUN, AGENTS, TICKS = new_run_id(), 7, 130  # shards of agents 0-2 and 3-6
PARAMS = params_for("paper")


def population_state(seed=0) -> dict[str, np.ndarray]:
    """A made-up run of the whole population: every array [TICKS, AGENTS, ...]."""
    rng = np.random.default_rng(seed)
    return {
        "sensors": rng.uniform(0, 10, (TICKS, AGENTS, len(SENSORS))),
        "pos": rng.uniform(-20, 20, (TICKS, AGENTS, 2)),
        "heading": rng.uniform(0, 360, (TICKS, AGENTS)),
        "events": rng.integers(0, 2, (TICKS, AGENTS, 4)),
        "collisions": np.cumsum(rng.integers(0, 2, (TICKS, AGENTS)), axis=0),
        "food": np.cumsum(rng.integers(0, 2, (TICKS, AGENTS)), axis=0),
    }


def shard_state(whole, lo, hi, tick, end, changes=(), final=False, **slice_) -> WorldState:
    """Ticks tick..end-1 of agents lo..hi-1, as world shard lo..hi-1 sends them (changes: its arenas)."""
    return WorldState.of(
        {n: a[tick:end, lo:hi] for n, a in whole.items()},
        changes,
        tick=tick,
        run=RUN,
        sensor_names=SENSORS,
        final=final,
        first=slice_.get("first", lo),
        population=slice_.get("population", AGENTS),
        shards=slice_.get("shards", 2),
    )


def shard_map(lo, hi, population=AGENTS, shards=2) -> WorldMap:
    grid = np.stack([generate_map(PARAMS, a) for a in range(lo, hi)])
    return WorldMap(
        tick=0,
        run=RUN,
        grid=Array.of(grid),
        x_min=PARAMS.x_min,
        y_min=PARAMS.y_min,
        first=lo,
        population=population,
        shards=shards,
    )


def joined(messages) -> tuple[list, dict[str, np.ndarray]]:
    join, out = ShardJoin(), []
    for m in messages:
        out += join.take(m)
    states = [m for m in out if isinstance(m, WorldState)]
    return out, {n: np.concatenate([getattr(m, n).numpy(n, *d) for m in states]) for n, d in ARRAYS.items()}


ARRAYS = {"pos": ("<f8", 3), "sensors": ("<f8", 3), "heading": ("<f8", 2), "events": ("<i8", 3), "food": ("<i8", 2)}


def test_a_shards_message_holds_one_of_its_n_slices():
    for population in (1, 7, 100, 4000, 2**31 - 1):
        for n in (*range(1, min(population, 12) + 1), population):
            for i in (*range(1, min(n, 12) + 1), n):
                lo, hi = shard_slice(population, (i, n))
                check_slice(lo, hi - lo, population, n, "agents")
    for first, agents, population, shards, why in (
        (1, 3, 7, 2, r"agents 1\.\.3: not one of 2 world shards' slices of 7"),
        (4, 3, 7, 2, r"agents 4\.\.6: not one of 2 world shards' slices of 7"),
        (0, 1, 2**31 - 1, 2**31 - 1, None),
        (0, 2, 2**31 - 1, 2**31 - 1, "not one of"),
        (3, 4, 7, 8, "8 world shards of a population of 7"),
        (3, 4, 7, 0, "0 world shards of a population of 7"),
        (3, 4, 0, 0, "first agent 3, 0 shards in a whole world"),
    ):
        if why is None:
            check_slice(first, agents, population, shards, "agents")
        else:
            with pytest.raises(BusError, match=why):
                check_slice(first, agents, population, shards, "agents")


def test_shards_in_batches_of_their_own_make_the_populations_state_and_map():
    whole = population_state()
    # shard 1 in batches of 50 ticks, shard 2 of 40, shard 2's first before shard 1's; agent 4 (shard 2's arena 1) eats
    ones = [shard_state(whole, 0, 3, t, min(t + 50, TICKS), final=t + 50 >= TICKS) for t in range(0, TICKS, 50)]
    twos = [
        shard_state(whole, 3, 7, t, min(t + 40, TICKS), [(t + 5, 1, 10, 12, 0)], final=t + 40 >= TICKS)
        for t in range(0, TICKS, 40)
    ]
    messages = [shard_map(3, 7), twos[0], shard_map(0, 3), ones[0], *twos[1:], *ones[1:]]
    out, arrays = joined(messages)
    assert isinstance(out[0], WorldMap) and out[0].population == 0
    np.testing.assert_array_equal(out[0].grid.numpy("grid", "|u1", 3), shard_map(0, 7, 7).grid.numpy("grid", "|u1", 3))
    states = out[1:]
    assert [(m.tick, m.pos.shape[0]) for m in states] == [(0, 40), (40, 10), (50, 30), (80, 20), (100, 20), (120, 10)]
    assert [m.final for m in states] == [False] * 5 + [True] and all(m.population == 0 for m in states)
    for name, values in arrays.items():
        np.testing.assert_array_equal(values, whole[name], err_msg=name)
    changes = np.concatenate([m.changes.numpy("changes", "<i8", 2) for m in states])
    assert changes.tolist() == [[t + 5, 4, 10, 12, 0] for t in range(0, TICKS, 40)]  # agent 4's arena


def test_ticks_one_shard_lost_are_left_out_of_every_shards():
    whole = population_state()
    ones = [shard_state(whole, 0, 3, t, t + 50) for t in (0, 50)]
    twos = [shard_state(whole, 3, 7, t, t + 40) for t in (0, 80)]  # ticks 40..79 lost on the way
    _, arrays = joined([*ones, *twos])
    np.testing.assert_array_equal(arrays["pos"], whole["pos"][np.r_[0:40, 80:100]])


def test_a_shard_that_sends_no_state_is_named():
    """One shard publishing alone (--publish-state on shard 1 only) joins no tick: the recorder
    names the shard whose state never came rather than end with an empty recording in silence."""
    whole, join = population_state(), ShardJoin()
    assert join.silent() == []
    assert join.take(shard_state(whole, 0, 3, 0, TICKS, final=True)) == []
    assert join.silent() == ["2/2 (agents 3..6)"]
    join.take(shard_state(whole, 3, 7, 0, TICKS, final=True))
    assert join.silent() == []


def forged(whole):
    """Shard states that are not of a shard of the population the recording holds, and why."""
    return [
        (shard_state(whole, 4, 7, 0, 10), "agents 4..6: not one of 2 world shards' slices of 7"),  # decoding
        (shard_state(whole, 4, 7, 0, 10, shards=3), "one of 3 shards of 7 agents; the recording's are 2 of 7"),
        (shard_state(whole, 3, 6, 0, 10, population=6), "one of 2 shards of 6 agents; the recording's are 2 of 7"),
        (shard_state(whole, 3, 7, 0, 10, [(3, 4, 0, 0, 1)]), "a map change outside its arenas"),  # arena 4 of 4
        (shard_state(whole, 0, 3, 10, 20), "a state after its final batch"),
    ]


def test_a_forged_shard_state_is_refused_and_the_recording_goes_on(tmp_path):
    whole = population_state()
    out_of_range = encode(shard_state(whole, 3, 7, 0, 10, first=4))  # agents 4..7 of 7
    with pytest.raises(BusError, match=r"agents 4\.\.7 outside the population of 7"):
        decode(out_of_range)
    rec = rr.RecordingStream("spikinglab-test", recording_id="shards")
    rec.save(str(tmp_path / "shards.rrd"))
    recorder = Recorder(rec, detail=(4,))
    recorder.on(shard_map(0, 3))
    recorder.on(shard_state(whole, 0, 3, 0, 20, final=True))
    for message, why in forged(whole):
        with pytest.raises(BusError, match=why):
            recorder.on(decode(encode(message)))
    recorder.on(shard_map(3, 7))
    recorder.on(shard_state(whole, 3, 7, 0, 20, final=True))
    assert recorder.world_done and recorder.agents == AGENTS
    recorder.close()
    rec.flush()
    rec.disconnect()
    data = read(tmp_path / "shards.rrd")
    assert data["/world/insects"]["tick"] == list(range(20))
    assert [len(points) for points in data["/world/insects"]["Points2D:positions"]] == [AGENTS] * 20
    assert data["/world/heading/agent4"]["tick"] == list(range(20))  # a detail agent of shard 2


def test_a_shard_message_of_another_map_size_or_a_second_map_is_refused():
    join = ShardJoin()
    join.take(shard_map(0, 3))
    with pytest.raises(BusError, match="a second map, not the one it began on"):
        join.take(msgspec.structs.replace(shard_map(0, 3), x_min=PARAMS.x_min + 1))
    with pytest.raises(BusError, match="another shard's is of"):
        join.take(msgspec.structs.replace(shard_map(3, 7), y_min=PARAMS.y_min - 1))


def test_a_refused_shard_message_leaves_nothing_behind():
    """Shard 3 of 3 (agents 4..6) with a change outside its arenas: refused, and the shards of 2
    that come after it are not held to its number of shards."""
    whole, join = population_state(), ShardJoin()
    with pytest.raises(BusError, match="a map change outside its arenas"):
        join.take(shard_state(whole, 4, 7, 0, 10, [(3, 3, 0, 0, 1)], shards=3))
    join.take(shard_state(whole, 0, 3, 0, 10))
    assert len(join.take(shard_state(whole, 3, 7, 0, 10))) == 1
