"""A service that leaves the bus of its own accord is news; one killed is a warning."""

import logging
import subprocess
import sys
import textwrap

from services.bus.config import session_for
from services.bus.transport import Bus

from ..processes import endpoint, wait_for

JOINING = textwrap.dedent("""
    import sys, time
    from services.bus.config import session_for
    from services.bus.transport import Bus
    bus = Bus(session_for(connect=[sys.argv[1]]), "leaving", sys.argv[2])
    print("joined", flush=True)
    sys.stdin.readline()  # until told to leave (or killed)
    bus.close()
""")


def test_an_orderly_leave_is_news_and_a_killed_process_a_warning(tmp_path, caplog):
    listen = endpoint(tmp_path, "watcher")
    watcher = Bus(session_for(listen=[listen]), "leaving", "recorder")
    watcher.watch_others()
    started = [
        subprocess.Popen(
            [sys.executable, "-c", JOINING, listen, service], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        for service in ("world", "brain")
    ]
    try:
        with caplog.at_level(logging.INFO, logger="spikinglab.bus"):
            for process in started:
                assert process.stdout is not None and process.stdout.readline() == "joined\n"
            wait_for(lambda: caplog.text.count("is on the bus") == 2, 10, "both to join")
            world, brain = started
            world.communicate("\n", timeout=30)  # leaves: Bus.close()
            brain.kill()
            wait_for(lambda: caplog.text.count("left the bus") == 2, 10, "both to leave")
    finally:
        for process in started:
            process.kill()
        watcher.close()
    said = {record.getMessage(): record.levelname for record in caplog.records if "left the bus" in record.getMessage()}
    assert said == {"the world left the bus": "INFO", "the brain left the bus": "WARNING"}
