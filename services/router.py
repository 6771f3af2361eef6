"""`spikinglab router`: a Zenoh router for brain, world, gateway and recorder on several machines.

Run it on any machine the others can reach; start each service with --connect tcp/HOST:7447.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

from services.bus.config import Session, add_bus_args
from services.options import Parser
from services.runtime import service_main

log = logging.getLogger("spikinglab.router")
DEFAULT_LISTEN = "tcp/0.0.0.0:7447"


def parser() -> Parser:
    p = Parser(
        prog="spikinglab router",
        description=f"A Zenoh router for services on several machines; without --listen it listens on {DEFAULT_LISTEN} "
        "(every interface).",
    )
    add_bus_args(p, group=False)  # it routes every group's keys
    return p


def listen_by_default(args: argparse.Namespace) -> None:
    if not args.listen:
        args.listen = [DEFAULT_LISTEN]


def run(args: argparse.Namespace, session: Session) -> int:
    """Route until Ctrl-C or SIGTERM."""
    log.info("router %s listening on %s", session.zid(), ", ".join(args.listen))
    while True:  # service_main closes the session on the way out
        time.sleep(1)


def main(argv=None) -> int:
    return service_main("router", parser(), run, argv, interrupted=0, prepare=listen_by_default, mode="router")


if __name__ == "__main__":
    sys.exit(main())
