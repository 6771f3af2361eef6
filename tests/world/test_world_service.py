"""The world service's messages, without the bus."""

import numpy as np
import pytest
import rerun as rr

from services.bus.batching import TickBatch
from services.bus.schemas import WorldState, decode, encode
from services.recorder.recorder import Recorder
from services.world.state import state_message
from services.world.world import World


def test_a_run_ended_before_its_first_tick_still_sends_a_final_state():
    """Ctrl-C while the brain was still compiling: no tick kept, and the recorder must still hear
    that the world is done (a KeyError here once killed the world and hung the run)."""
    world = World(agents=2)
    message = decode(encode(state_message(TickBatch(50), [], True, world, "0123456789abcdef")), WorldState)
    assert isinstance(message, WorldState)
    assert message.final and message.tick == 0 and message.pos.shape == (0, 2, 2)
    recorder = Recorder(rr.RecordingStream("spikinglab-test"))
    recorder.on(message)
    assert recorder.world_done and recorder.agents == 2


def test_a_checkpoint_resumes_only_under_the_options_that_made_it(tmp_path):
    from services.options import config_from
    from services.world.checkpoint import CHECKPOINT, PENDING, keep_checkpoint, resume
    from services.world.options import world_from
    from services.world.results import Trajectory
    from services.world.service import WorldConfig, parser

    made = config_from(parser().parse_args(["--seed", "4", "--ticks", "3000"]), WorldConfig).world
    world = world_from(made)
    for _ in range(1200):
        world.sense()
        world.act(np.array([[1, 1]], np.uint8))
    keep_checkpoint(tmp_path, made, world, Trajectory(world, made.ticks), "0123456789abcdef")
    again = world_from(made)
    assert resume(tmp_path, made, again, Trajectory(again, made.ticks)) is None  # until the brain has answered its tick
    (tmp_path / PENDING).replace(tmp_path / CHECKPOINT)
    assert resume(tmp_path, made, again, Trajectory(again, made.ticks)) == "0123456789abcdef"
    assert again.tick == 1200 and np.array_equal(again.pos, world.pos) and len(again.metrics.bins) == 1
    other = config_from(parser().parse_args(["--seed", "5", "--ticks", "3000"]), WorldConfig).world
    with pytest.raises(ValueError, match=r"other options \(--seed 4 there, 5 here\)"):
        resume(tmp_path, other, world_from(other), Trajectory(world_from(other), other.ticks))
    (tmp_path / "world.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="not a run checkpoint"):
        resume(tmp_path, made, world_from(made), Trajectory(world, made.ticks))


def test_a_checkpoint_knows_its_map_by_its_contents_not_its_path(tmp_path):
    """The same map in another place (a run folder reached by another path) resumes; an edited map
    is refused before the world is restored into an arena of another size."""
    from services.options import config_from
    from services.world.checkpoint import CHECKPOINT, PENDING, keep_checkpoint, resume
    from services.world.options import world_from
    from services.world.results import Trajectory
    from services.world.service import WorldConfig, parser

    arena = "##########\n#S...R...#\n#..G.....#\n##########\n"
    (tmp_path / "here.txt").write_text(arena)
    (tmp_path / "there.txt").write_text(arena)
    (tmp_path / "edited.txt").write_text("############\n#S.........#\n############\n")

    def made(name: str):
        return config_from(parser().parse_args(["--map", str(tmp_path / name)]), WorldConfig).world

    (tmp_path / "kept").mkdir()
    keep_checkpoint(
        tmp_path / "kept",
        made("here.txt"),
        world_from(made("here.txt")),
        Trajectory(world_from(made("here.txt")), 40_000),
        "0123456789abcdef",
    )
    (tmp_path / "kept" / PENDING).replace(tmp_path / "kept" / CHECKPOINT)
    there = world_from(made("there.txt"))
    assert resume(tmp_path / "kept", made("there.txt"), there, Trajectory(there, 40_000)) == "0123456789abcdef"
    edited = world_from(made("edited.txt"))
    with pytest.raises(
        ValueError, match=r"other options \(--map \(its file's SHA-256\) [0-9a-f]{12} there, [0-9a-f]{12} here\)"
    ):
        resume(tmp_path / "kept", made("edited.txt"), edited, Trajectory(edited, 40_000))
