"""A second brain for the agents a brain already serves (same group, same shard), started while a
run goes on: it says so in one line and exits non-zero, and the run goes on with the first."""

import json
import signal
import time

from services.bus import keys
from tests.processes import Watcher, endpoint, finish, start, wait_for


def test_a_second_brain_for_the_same_agents_says_so_and_exits(tmp_path):
    world_ep = endpoint(tmp_path, "world")
    group = ("--group", "twice")
    world = start(
        "world", *group, "--listen", world_ep, "--ticks", 10_000_000, "--out", tmp_path, log=tmp_path / "world.log"
    )
    first = start("brain", *group, "--connect", world_ep, "--once", log=tmp_path / "brain1.log")
    second = None
    try:
        wait_for(lambda: "brain for 1 agent" in (tmp_path / "brain1.log").read_text(), 60, "the first brain's run")
        started = time.monotonic()
        second = start("brain", *group, "--connect", world_ep, "--once", log=tmp_path / "brain2.log")
        assert finish(second, 60, tmp_path / "brain2.log") == 1
        print(f"second brain: started, said so and exited in {time.monotonic() - started:.1f} s")
        assert world.poll() is None and first.poll() is None  # the run goes on with the first brain
        answers = Watcher([world_ep], [keys.motor("twice")])
        try:  # however slowly a cold machine compiles the brain: the run is under way
            wait_for(lambda: len(answers.messages[keys.motor("twice")]) > 1, 120, "the first brain's answers")
        finally:
            answers.close()
        world.send_signal(signal.SIGTERM)  # the world ends the run there: the first brain ends with it
        assert finish(world, 60, tmp_path / "world.log") == 130  # interrupted: its metrics marked partial
        assert finish(first, 30, tmp_path / "brain1.log") == 0
    finally:
        for process in (world, first, second):
            if process is not None:
                process.kill()
    said = (tmp_path / "brain2.log").read_text().strip().splitlines()
    assert len(said) == 1 and "another brain already serves the agents of group twice" in said[0], said
    assert keys.alive("twice", "brain") in said[0]
    assert "run ended" in (tmp_path / "brain1.log").read_text()
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["ticks"] > 0 and not metrics["rejected_messages"]  # no answer from a second brain
