"""`spikinglab router`: a Zenoh router for brain, world, gateway and recorder on several machines.

Run it on any machine the others can reach; start each service with --connect tcp/HOST:7447.
"""

from __future__ import annotations

import logging
import sys
import time

from services.bus.config import BusConfigError, add_bus_args, open_session
from services.options import Parser

log = logging.getLogger("spikinglab.router")


def parser() -> Parser:
    p = Parser(prog="spikinglab router", description=__doc__.splitlines()[0])
    add_bus_args(p)
    return p


def main(argv=None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s router %(levelname)s %(message)s", stream=sys.stderr)
    args = parser().parse_args(argv)
    if not args.listen:
        args.listen = ["tcp/0.0.0.0:7447"]
    try:
        session = open_session(args, mode="router")
    except BusConfigError as e:
        raise SystemExit(str(e)) from None
    log.info("router %s listening on %s", session.zid(), ", ".join(args.listen))
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        return 0
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
