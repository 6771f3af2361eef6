"""A service's bus options and its Zenoh session config.

Every service adds the same options (`add_bus_args`): --connect/--listen endpoints, --zenoh-config
FILE for anything else (TLS, access control), --group, --cpu. Multicast scouting is off unless the
config file turns it on: sessions find each other through the endpoints given.
"""

from __future__ import annotations

import argparse
import datetime
import json
import logging
import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import json5
import zenoh

from services.options import at_least

from . import keys

log = logging.getLogger("spikinglab.bus")
Session = zenoh.Session  # for the services' annotations: outside services/bus no module imports zenoh


class BusConfigError(ValueError):
    """The bus session cannot be configured or opened; the text says with what."""


NOTHING_ANSWERS_AFTER = 10.0  # seconds: then a --connect that reached nobody is reported
# what this Zenoh can listen and connect on (its unixpipe, vsock and serial are not built in)
PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream")
# transport.link.tls's fields that name a file (what `spikinglab certs` writes into its configs)
RUST_PLACE = re.compile(r" at /\S+?\.rs:\d+\.?")  # " at /root/.cargo/.../tcp.rs:61." in Zenoh's errors
TLS_FILES = (
    "root_ca_certificate",
    "listen_certificate",
    "listen_private_key",
    "connect_certificate",
    "connect_private_key",
)


def endpoint(text: str) -> str:
    """A Zenoh endpoint, checked before anything starts: <protocol>/<address>, and host:port for
    the IP protocols (argparse turns the ArgumentTypeError into a usage error naming the option)."""
    protocol, _, address = text.partition("/")
    if protocol not in PROTOCOLS or not address:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not an endpoint: expected <protocol>/<address> with protocol "
            f"one of {', '.join(PROTOCOLS)}, e.g. tcp/192.168.1.10:7447"
        )
    if protocol in ("tcp", "udp", "tls", "quic"):
        host, _, port = address.split("#")[0].split("?")[0].rpartition(":")
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise argparse.ArgumentTypeError(
                f"{text!r}: a {protocol} endpoint needs host:port with a port of 0-65535, e.g. tcp/192.168.1.10:7447"
            )
    return text


def group_name(text: str) -> str:
    """--group: one key segment."""
    try:
        return keys.check_group(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def add_bus_args(parser: argparse.ArgumentParser, group: bool = True) -> None:
    """The bus options; `group` False for the router, which routes every group's keys."""
    bus = parser.add_argument_group("bus")
    bus.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        type=endpoint,
        help="endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)",
    )
    bus.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        type=endpoint,
        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)",
    )
    bus.add_argument(
        "--zenoh-config",
        metavar="FILE",
        type=zenoh_config_file,
        help="a Zenoh JSON5 config file (TLS, access control: spikinglab certs writes them)",
    )
    if group:
        bus.add_argument(
            "--group",
            type=group_name,
            default=keys.DEFAULT_GROUP,
            help=f"the insect or population this service belongs to (default {keys.DEFAULT_GROUP})",
        )
    bus.add_argument(
        "--cpu",
        type=cpu_number,
        metavar="N",
        help="run this process on CPU N only (a lock-step pair on separate cores is ~30 %% faster)",
    )


def cpu_number(text: str) -> int:
    """--cpu: a CPU this process may run on (Linux says which), refused before start rather than
    warned of once the process runs elsewhere."""
    cpu = at_least(0)(text)
    usable = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    if usable is not None and cpu not in usable:
        cpus = ", ".join(map(str, sorted(usable)))
        raise argparse.ArgumentTypeError(f"CPU {cpu} is not one this process may use ({cpus})")
    return cpu


@dataclass(frozen=True)
class BusConfig:
    """add_bus_args' options, in every service's config (services.options.config_from)."""

    connect: list[str]
    listen: list[str]
    zenoh_config: dict | None  # zenoh_config_file's
    group: str
    cpu: int | None


def zenoh_config_file(text: str) -> dict:
    """A --zenoh-config file, read as JSON5 before anything starts (argparse names the option)."""
    try:
        settings = json5.loads(Path(text).read_text())
    except OSError as e:
        raise argparse.ArgumentTypeError(
            f"cannot read {text}: {e.strerror} (`spikinglab certs DIR` writes one for each service)"
        ) from None
    except ValueError as e:  # json5's parse errors, and a file that is not UTF-8
        raise argparse.ArgumentTypeError(f"{text} is not a JSON5 config: {e}") from None
    if not isinstance(settings, dict):
        raise argparse.ArgumentTypeError(f"{text} should hold one JSON5 object {{...}}, not {type(settings).__name__}")
    missing = missing_tls_file(settings)
    if missing:
        raise argparse.ArgumentTypeError(f"{text}: {missing} (copy it there, or edit the path in {text})")
    unfit = unfit_certificate(settings)
    if unfit:
        raise argparse.ArgumentTypeError(f"{text}: {unfit}")
    return {"file": text, "settings": settings}


def missing_tls_file(settings: dict) -> str | None:
    """The first certificate or key file the config names that cannot be read, with why; Zenoh
    itself says only that a TLS link timed out, or that a key is missing."""
    tls = setting(settings, "transport", "link", "tls")
    if not isinstance(tls, dict):
        return None
    for field in TLS_FILES:
        path = tls.get(field)
        if isinstance(path, str):
            try:
                Path(path).open("rb").close()
            except OSError as e:
                return f"transport.link.tls.{field} {path}: {e.strerror}"
    return None


def unfit_certificate(settings: dict) -> str | None:
    """The first certificate the config names that is expired, not yet valid, or not signed by
    its root CA, with why; Zenoh itself says only that the TLS link timed out."""
    tls = setting(settings, "transport", "link", "tls")
    if not isinstance(tls, dict) or not isinstance(tls.get("root_ca_certificate"), str):
        return None
    from cryptography import x509  # only for a config with TLS
    from cryptography.exceptions import InvalidSignature

    now = datetime.datetime.now(datetime.UTC)
    ca = None
    for field in ("root_ca_certificate", "listen_certificate", "connect_certificate"):
        path = tls.get(field)
        if not isinstance(path, str):
            continue
        where = f"transport.link.tls.{field} {path}"
        try:
            cert = x509.load_pem_x509_certificate(Path(path).read_bytes())
        except ValueError:
            return f"{where}: not a PEM certificate"
        if now > cert.not_valid_after_utc or now < cert.not_valid_before_utc:
            return (
                f"{where}: valid from {cert.not_valid_before_utc:%Y-%m-%d %H:%M} to "
                f"{cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC, not now (`spikinglab certs` makes new ones)"
            )
        if ca is None:
            ca = cert
            continue
        try:
            cert.verify_directly_issued_by(ca)
        except (ValueError, TypeError, InvalidSignature):
            return (
                f"{where}: not signed by the CA of {tls['root_ca_certificate']} (certificates of one "
                "`spikinglab certs` folder go together)"
            )
    return None


def make_config(connect=(), listen=(), config_file: dict | None = None, mode: str | None = None) -> zenoh.Config:
    """A session's config: the --zenoh-config file's settings if given, then these. The mode is
    `mode` if given (a router), else the file's, else peer; multicast scouting stays off unless
    the file turns it on (sessions find each other through the endpoints given); a client waits up
    to NOTHING_ANSWERS_AFTER for its router unless the file says otherwise."""
    settings = dict(config_file["settings"]) if config_file else {}
    if mode is not None or "mode" not in settings:
        settings["mode"] = mode or "peer"
    scouting = settings.setdefault("scouting", {})
    scouting.setdefault("multicast", {}).setdefault("enabled", False)
    if settings["mode"] == "client":  # a client cannot open without its router: wait for one started with it
        timeouts = settings.setdefault("connect", {}).setdefault("timeout_ms", {})
        if isinstance(timeouts, dict):
            timeouts.setdefault("client", int(NOTHING_ANSWERS_AFTER * 1000))
    if connect:
        settings.setdefault("connect", {})["endpoints"] = list(connect)
    if listen:
        settings.setdefault("listen", {})["endpoints"] = list(listen)
    try:
        return zenoh.Config.from_json5(json.dumps(settings))
    except Exception as e:  # zenoh's own error type: a key or value it does not take
        where = f"--zenoh-config {config_file['file']}" if config_file else "the bus config"
        raise BusConfigError(f"{where}: {zenoh_says(e)}") from None


def session_for(connect=(), listen=(), config_file: dict | None = None, mode: str | None = None) -> Session:
    """A session opened with make_config's settings; a clear error when zenoh refuses them."""
    try:
        return zenoh.open(make_config(connect, listen, config_file, mode))
    except zenoh.ZError as e:
        reason = zenoh_says(e)
        endpoints = connect_endpoints(connect, config_file)
        if "Unable to connect" in reason and not all(point.startswith("tls/") for point in endpoints):
            # Zenoh says only "Timeout!" when a TLS router is given a tcp/ endpoint
            reason += "; a router secured with TLS is reached at its tls/ endpoint (docs/security.md)"
        raise BusConfigError(
            f"cannot open the bus session (connect {list(connect)}, listen {list(listen)}): {reason}"
        ) from None


def zenoh_says(error: Exception) -> str:
    """Zenoh's error without the Rust source locations it gives, at every level of its nesting."""
    return RUST_PLACE.sub("", str(error)).strip()


def connect_endpoints(connect, config_file: dict | None) -> list[str]:
    """The endpoints a session connects to: --connect's, else its config file's."""
    if connect:
        return list(connect)
    endpoints = setting(config_file["settings"], "connect", "endpoints") if config_file else None
    return [e for e in endpoints if isinstance(e, str)] if isinstance(endpoints, list) else []


def setting(settings: dict, *path: str):
    """settings[path[0]][path[1]]... of a config file, or None where a table on the way is missing
    (or is not a table)."""
    found = settings
    for name in path:
        found = found.get(name) if isinstance(found, dict) else None
    return found


def open_session(args: argparse.Namespace, mode: str | None = None) -> Session:
    if getattr(args, "cpu", None) is not None:  # before zenoh starts its threads, so they stay there too
        try:
            os.sched_setaffinity(0, {args.cpu})
        except (OSError, AttributeError) as e:
            usable = ", ".join(map(str, sorted(os.sched_getaffinity(0)))) if hasattr(os, "sched_getaffinity") else "?"
            log.warning("cannot pin to CPU %d (this process may use CPUs %s): %s", args.cpu, usable, e)
    session = session_for(args.connect, args.listen, args.zenoh_config, mode)
    if not (args.connect or args.listen or args.zenoh_config or mode == "router"):  # a router listens on 7447
        log.warning(
            "no --connect and no --listen: no other process knows where to reach this one (it listens on a "
            "port of Zenoh's choosing, and multicast scouting is off); "
            "give it --listen ENDPOINT and the others --connect ENDPOINT (docs/bus.md)"
        )
    if args.connect:
        threading.Thread(
            target=report_if_alone,
            args=(session, args.connect, args.zenoh_config is None),
            daemon=True,
            name="connection check",
        ).start()
    return session


def report_if_alone(session: Session, connect: list[str], no_config: bool = False) -> None:
    """Say so when none of the --connect endpoints answered within NOTHING_ANSWERS_AFTER seconds;
    Zenoh keeps trying meanwhile (the other side may start later). `no_config`: no --zenoh-config
    was given, so a tls/ endpoint has no certificates to connect with."""
    deadline = time.monotonic() + NOTHING_ANSWERS_AFTER
    while time.monotonic() < deadline:
        try:
            if any(True for _ in session.info.peers_zid()) or any(True for _ in session.info.routers_zid()):
                return
        except Exception:  # the session closed meanwhile
            return
        time.sleep(0.25)
    # a TLS router answers a session without certificates as nothing does: say what is missing
    certificates = any(e.startswith("tls/") for e in connect) and no_config
    log.warning(
        "nothing answers at %s after %.0f s (is the other side running, and is the endpoint right?); still trying%s",
        ", ".join(connect),
        NOTHING_ANSWERS_AFTER,
        "; a tls/ endpoint needs --zenoh-config with this machine's certificates (docs/security.md)"
        if certificates
        else "",
    )
