"""A bare Zenoh ping-pong between two processes: the bound the lock-step loop is measured against.

`python -m services.bus.pingpong pong --listen EP [--cpu N]` answers every ping on
spikinglab/bench/ping with the same bytes on spikinglab/bench/pong; `ping --connect EP --count N
[--cpu N]` sends N pings one after the other, each after the last pong, and prints the round trips
per second as JSON. Publishers and subscribers are set up as the lock-step ones are (express,
congestion control BLOCK, a FIFO channel read in a blocking recv), with no schema on top.
"""

from __future__ import annotations

import json
import sys
import time

import zenoh

from services.options import Parser, at_least

from .config import add_bus_args, open_session

PING, PONG = "spikinglab/bench/ping", "spikinglab/bench/pong"
PAYLOAD = bytes(64)  # about a one-agent Sensors message's size class


def main(argv=None) -> int:
    p = Parser(prog="python -m services.bus.pingpong", description=(__doc__ or "").partition("\n")[0])
    p.add_argument("role", choices=("ping", "pong"))
    p.add_argument("--count", type=at_least(1), default=20_000)
    add_bus_args(p)
    args = p.parse_args(argv)
    session = open_session(args)
    mine, theirs = (PING, PONG) if args.role == "ping" else (PONG, PING)
    publisher = session.declare_publisher(mine, congestion_control=zenoh.CongestionControl.BLOCK, express=True)
    inbox = session.declare_subscriber(theirs, zenoh.handlers.FifoChannel(1024))
    try:
        if args.role == "pong":
            while True:
                publisher.put(inbox.recv().payload)
        answered = False
        while not answered:  # until the pong answers (its publisher may learn of our subscriber late)
            publisher.put(PAYLOAD)
            waited = time.monotonic()
            while not answered and time.monotonic() - waited < 0.2:
                answered = inbox.try_recv() is not None
                time.sleep(0.001)
        time.sleep(0.3)
        while inbox.try_recv() is not None:  # pongs to the repeated first pings
            pass
        for _ in range(200):  # warm up
            publisher.put(PAYLOAD)
            inbox.recv()
        started = time.perf_counter()
        for _ in range(args.count):
            publisher.put(PAYLOAD)
            inbox.recv()
        rate = args.count / (time.perf_counter() - started)
        print(json.dumps({"roundtrips_per_s": round(rate)}))
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
