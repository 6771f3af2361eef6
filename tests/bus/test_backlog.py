"""A reader that falls behind keeps at most its backlog's bytes waiting; the rest is dropped and counted."""

import numpy as np
import zenoh

from services.bus.config import make_config
from services.bus.schemas import Array, BrainState, encode
from services.bus.transport import DROPPED, Inbox, wait_until


def test_a_reader_that_falls_behind_keeps_its_backlog_and_counts_the_rest():
    message = BrainState(
        tick=0,
        run="0123456789abcdef",
        spiked=Array.of(np.zeros((50, 20, 15), np.uint8)),
        potentials=Array.of(np.zeros((50, 20, 11), np.float32)),
        weights=Array.of(np.ones((20, 16))),
    )
    payload = encode(message)  # about 60 KB
    with zenoh.open(make_config()) as session:
        inbox = Inbox(session, "backlog/test", BrainState, backlog_bytes=1 << 20)
        try:
            for _ in range(100):  # 6 MB sent while nobody reads
                session.put("backlog/test", payload)
            held = (1 << 20) // len(payload)
            assert wait_until(lambda: inbox.dropped == 100 - held, 5), inbox.dropped
            got = 0
            while inbox.get(timeout=0.2) is not None:
                got += 1
            assert got == held and inbox.rejections() == {"backlog/test": {DROPPED: inbox.dropped}}
            session.put("backlog/test", payload)  # read: room again
            assert inbox.get(timeout=2) == message
        finally:
            inbox.close()
