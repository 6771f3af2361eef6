"""The world service's messages, without the bus."""

import rerun as rr

from spikinglab.bus.schemas import TickBatch, WorldState, decode, encode
from spikinglab.recorder.recorder import Recorder
from spikinglab.world.service import state_message
from spikinglab.world.world import World


def test_a_run_ended_before_its_first_tick_still_sends_a_final_state():
    """Ctrl-C while the brain was still compiling: no tick kept, and the recorder must still hear
    that the world is done (a KeyError here once killed the world and hung the run)."""
    world = World(agents=2)
    message = decode(encode(state_message(TickBatch(50), [], True, world, "0123456789abcdef")), WorldState)
    assert message.final and message.tick == 0 and message.pos.shape == (0, 2, 2)
    recorder = Recorder(rr.RecordingStream("spikinglab-test"))
    recorder.on(message)
    assert recorder.world_done and recorder.agents == 2
