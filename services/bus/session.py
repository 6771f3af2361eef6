"""Zenoh sessions, publishers, strict inboxes and liveliness: the only code that imports zenoh.

Every service adds the same options (`add_bus_args`): --connect/--listen endpoints, --zenoh-config
FILE for anything else (TLS, access control), --group. Multicast scouting is off unless the config
file turns it on: sessions find each other through the endpoints given.
"""

from __future__ import annotations

import _thread
import argparse
import collections
import json
import logging
import os
import queue
import signal
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import json5
import zenoh

from . import keys
from .schemas import BusError, Message, decode, encode

log = logging.getLogger("spikinglab.bus")


PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe", "vsock", "serial")
DROPPED = "dropped, backlog full"  # the reason counted for messages a Backlog dropped
REASONS_KEPT = 32  # distinct rejection reasons counted per key; the rest as "other reasons"
NOTHING_ANSWERS_AFTER = 10.0  # seconds: then a --connect that reached nobody is reported


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


def add_bus_args(parser: argparse.ArgumentParser) -> None:
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
    bus.add_argument(
        "--group",
        default=keys.DEFAULT_GROUP,
        help=f"the insect or population this service belongs to (default {keys.DEFAULT_GROUP})",
    )
    bus.add_argument(
        "--cpu",
        type=int,
        metavar="N",
        help="run this process on CPU N only (a lock-step pair on separate cores is ~30 %% faster)",
    )


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
    return {"file": text, "settings": settings}


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
        raise SystemExit(f"{where}: {str(e).split(' at /')[0]}") from None


def open_session(args: argparse.Namespace, mode: str | None = None) -> zenoh.Session:
    if getattr(args, "cpu", None) is not None:  # before zenoh starts its threads, so they stay there too
        try:
            os.sched_setaffinity(0, {args.cpu})
        except (OSError, AttributeError) as e:
            log.warning("cannot pin to CPU %d: %s", args.cpu, e)
    try:
        session = zenoh.open(make_config(args.connect, args.listen, args.zenoh_config, mode))
    except zenoh.ZError as e:
        reason = str(e).split(" at /")[0]  # without the Rust source location
        raise SystemExit(
            f"cannot open the bus session (connect {args.connect}, listen {args.listen}): {reason}"
        ) from None
    if args.connect:
        threading.Thread(
            target=report_if_alone, args=(session, args.connect), daemon=True, name="connection check"
        ).start()
    return session


def report_if_alone(session: zenoh.Session, connect: list[str]) -> None:
    """Say so when none of the --connect endpoints answered within NOTHING_ANSWERS_AFTER seconds;
    Zenoh keeps trying meanwhile (the other side may start later)."""
    deadline = time.monotonic() + NOTHING_ANSWERS_AFTER
    while time.monotonic() < deadline:
        try:
            if any(True for _ in session.info.peers_zid()) or any(True for _ in session.info.routers_zid()):
                return
        except Exception:  # the session closed meanwhile
            return
        time.sleep(0.25)
    log.warning(
        "nothing answers at %s after %.0f s (is the other side running, and is the endpoint right?); still trying",
        ", ".join(connect),
        NOTHING_ANSWERS_AFTER,
    )


def by_key(rejected: Counter) -> dict[str, dict[str, int]]:
    """Rejection counts {(key, reason): n} as {key: {reason: n}}."""
    out: dict[str, dict[str, int]] = {}
    for (key, reason), count in sorted(rejected.items()):
        out.setdefault(key, {})[reason] = count
    return out


class Backlog:
    """A subscriber's queue bounded in bytes, for readers that may fall behind (the recorder): a
    message that would take it past `limit` is dropped and counted, never held without limit.
    The same try_recv()/recv() as zenoh's channels; filled on zenoh's thread."""

    def __init__(self, limit: int):
        self.limit, self.size, self.dropped = limit, 0, 0
        self._items: collections.deque = collections.deque()
        self._ready = threading.Condition()

    def __call__(self, sample) -> None:
        n = len(sample.payload)
        with self._ready:
            if n and self.size + n > self.limit:
                self.dropped += 1
                return
            self._items.append(sample)
            self.size += n
            self._ready.notify()

    def try_recv(self):
        with self._ready:
            if not self._items:
                return None
            sample = self._items.popleft()
            self.size -= len(sample.payload)
            return sample

    def recv(self):
        with self._ready:
            self._ready.wait_for(lambda: self._items)
        return self.try_recv()


class Inbox:
    """A subscriber whose messages are decoded strictly: good ones are returned by `get()`, bad
    ones are counted and logged (key, sender, reason) and dropped whole. With `backlog_bytes`, what
    waits to be read is bounded (Backlog): more is dropped and counted as "dropped, backlog full".

    The owner's loop blocks in the channel's recv(), the fastest hand-over zenoh-python has
    (about 0.2 ms per lock-step round trip between two processes, against 0.28 ms through a
    Python callback and a queue). recv() has no timeout, so a ticker thread wakes it with an
    empty session-local sample when get()'s timeout passes, and every quarter second otherwise,
    so that Ctrl-C is seen.
    """

    WAKE_EVERY = 0.25

    def __init__(
        self, session: zenoh.Session, key: str, kinds, capacity: int = 100_000, backlog_bytes: int | None = None
    ):
        self.key, self.kinds = key, kinds
        self.rejected: Counter = Counter()
        self._session = session
        self._backlog = Backlog(backlog_bytes) if backlog_bytes else None
        self._sub = session.declare_subscriber(key, self._backlog or zenoh.handlers.FifoChannel(capacity))
        self._channel = self._backlog or self._sub
        self._deadline: float | None = None  # when the blocked owner wants to be woken
        self._closed = threading.Event()
        self._ticker = threading.Thread(target=self._tick, name=f"wake {key}", daemon=True)
        self._ticker.start()

    def _tick(self) -> None:
        while not self._closed.wait(0.02):
            deadline = self._deadline
            if deadline is not None and time.monotonic() >= deadline:
                self._deadline = None
                self._session.put(self.key, b"", allowed_destination=zenoh.Locality.SESSION_LOCAL)

    def get(self, timeout: float | None = None) -> Message | None:
        """The next good message; None once `timeout` seconds pass without one."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            sample = self._channel.try_recv()
            if sample is None:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    return None
                self._deadline = min(deadline, now + self.WAKE_EVERY) if deadline else now + self.WAKE_EVERY
                sample = self._channel.recv()
                self._deadline = None
            payload = sample.payload.to_bytes()
            if not payload:  # a wake-up
                continue
            try:
                return decode(payload, self.kinds)
            except BusError as e:
                self._reject(sample, e)

    def latest(self) -> Message | None:
        """The newest good message waiting, without blocking; the older ones are dropped undecoded
        (a free-running loop wants the current reading, not the history)."""
        waiting = []
        while (sample := self._channel.try_recv()) is not None:
            waiting.append(sample)
        for sample in reversed(waiting):
            payload = sample.payload.to_bytes()
            if not payload:
                continue
            try:
                return decode(payload, self.kinds)
            except BusError as e:
                self._reject(sample, e)
        return None

    def _reject(self, sample, error: BusError) -> None:
        sender = sample.attachment.to_bytes().decode(errors="replace") if sample.attachment else "unknown sender"
        self.refuse(error, f"from {sender}", key=str(sample.key_expr))

    def refuse(self, error: Exception, where: str = "", key: str | None = None) -> None:
        """Count a message rejected for `error` (by the decoder, or by the service because it does
        not fit its run), by key (this inbox's unless named) and reason; logged, but a flood does
        not drown the log."""
        key = key or self.key
        reason = str(error).split(":")[0]
        if (key, reason) not in self.rejected and sum(k == key for k, _ in self.rejected) >= REASONS_KEPT:
            reason = "other reasons"  # a flood of distinct reasons must not grow memory without bound
        self.rejected[(key, reason)] += 1
        total = self.rejected_total
        if total <= 20 or total % 1000 == 0:
            log.warning(
                "rejected message on %s%s: %s (%d rejected so far)", key, f" {where}" if where else "", error, total
            )

    @property
    def dropped(self) -> int:
        """Messages dropped because the backlog was full (the reader fell behind)."""
        return self._backlog.dropped if self._backlog else 0

    @property
    def counts(self) -> Counter:
        """Rejected and dropped messages: {(key, reason): n}."""
        return self.rejected + Counter({(self.key, DROPPED): self.dropped} if self.dropped else {})

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    def rejections(self) -> dict[str, dict[str, int]]:
        """Rejected (and dropped) messages so far: {key: {reason: count}}."""
        return by_key(self.counts)

    def close(self) -> None:
        # join the ticker: a daemon thread still inside a zenoh call when Python finalises is
        # force-exited mid Rust frame, and glibc aborts ("FATAL: exception not rethrown")
        self._closed.set()
        self._ticker.join(timeout=2)
        self._sub.undeclare()


class Outbox:
    """A publisher of messages; express: sent at once, not batched. BLOCK congestion control: no
    message is dropped when the link is busy (lock-step counts on every one); `lossy`: DROP, for
    streams that must never hold the run back (the recording: a frozen recorder would stall the
    world; it counts the ticks missing instead)."""

    def __init__(self, session: zenoh.Session, key: str, sender: str, lossy: bool = False):
        self.key = key
        self._sender = sender.encode()
        control = zenoh.CongestionControl.DROP if lossy else zenoh.CongestionControl.BLOCK
        self._pub = session.declare_publisher(key, congestion_control=control, express=True)

    def put(self, message: Message) -> None:
        self._pub.put(encode(message), attachment=self._sender)

    @property
    def matched(self) -> bool:
        """Whether a subscriber for this key is known to the session."""
        status = self._pub.matching_status
        return bool(getattr(status, "matching", status))

    def close(self) -> None:
        self._pub.undeclare()


class Presence:
    """Watches the liveliness tokens of one service of a group: how many are alive, and changes."""

    def __init__(self, session: zenoh.Session, group: str, service: str, on_change=None):
        self.service = service
        self._alive: set[str] = set()
        self.seen = False  # whether one has been alive since this watch began
        self._changed = threading.Condition()
        self._on_change = on_change  # called with ("up" | "down", key) on zenoh's thread
        self.events: queue.Queue = queue.Queue()  # ("up" | "down", key)
        self._sub = session.liveliness().declare_subscriber(keys.alive(group, service), self._on_sample, history=True)

    def _on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        up = sample.kind == zenoh.SampleKind.PUT
        self.seen = self.seen or up
        with self._changed:
            (self._alive.add if up else self._alive.discard)(key)
            self._changed.notify_all()
        if self._on_change is not None:
            self._on_change("up" if up else "down", key)
        else:
            self.events.put(("up" if up else "down", key))

    @property
    def alive(self) -> bool:
        return bool(self._alive)

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until at least one is alive; True if so."""
        with self._changed:
            return self._changed.wait_for(lambda: bool(self._alive), timeout)

    def close(self) -> None:
        self._sub.undeclare()


class Bus:
    """One service's place on the bus: its session, its liveliness token, its inboxes and outboxes."""

    def __init__(self, session: zenoh.Session, group: str, service: str):
        self.session, self.group, self.service = session, group, service
        self.sender = f"{service}@{os.getpid()}"
        self._token = session.liveliness().declare_token(keys.alive(group, service))
        self._owned: list = []

    def outbox(self, key: str, lossy: bool = False) -> Outbox:
        box = Outbox(self.session, key, self.sender, lossy)
        self._owned.append(box)
        return box

    def inbox(self, key: str, kinds, backlog_bytes: int | None = None) -> Inbox:
        box = Inbox(self.session, key, kinds, backlog_bytes=backlog_bytes)
        self._owned.append(box)
        return box

    def rejections(self) -> dict[str, dict[str, int]]:
        """Every inbox's rejected messages: {key: {reason: count}} (stats files, summary.json)."""
        return by_key(sum((box.counts for box in self._owned if isinstance(box, Inbox)), Counter()))

    def watch_others(self, where=lambda: "") -> None:
        """Log each other service of the group that joins or leaves the bus, with `where()` (the
        tick this one has reached): a killed process is seen within milliseconds, a frozen one
        when its lease ends (about 10 s), one behind a dead router with the router."""

        def on_change(change: str, key: str) -> None:
            service = key.rsplit("/", 1)[-1]
            if service == self.service:
                return
            try:
                context = where()
            except Exception:  # a context is a courtesy: never a reason to miss the news
                context = ""
            if change == "down":
                log.warning("the %s left the bus%s", service, context)
            else:
                log.info("the %s is on the bus%s", service, context)

        self._owned.append(Presence(self.session, self.group, "*", on_change))

    def presence(self, service: str) -> Presence:
        watch = Presence(self.session, self.group, service)
        self._owned.append(watch)
        return watch

    def close(self) -> None:
        for item in reversed(self._owned):
            try:
                item.close()
            except Exception:  # already gone with the session: nothing left to release
                pass
        self._token.undeclare()
        try:
            self.session.close()
        except zenoh.ZError as e:  # a peer that no longer answers (a frozen process): the work is done, say so
            log.warning("the bus session did not close cleanly (%s): a peer does not answer", str(e).split(" at /")[0])


_thread_died = threading.Event()


def guard_threads() -> None:
    """A thread of this process that dies of an exception takes the process down with it, the
    clean way: logged with its traceback, then the main thread is interrupted as by Ctrl-C (so the
    service stops its robot, saves and says goodbye) and the process exits 1. Never a process that
    stays on the bus looking alive while a part of it is dead."""

    def died(hook) -> None:
        if hook.exc_type is SystemExit:
            return
        log.critical(
            "thread %r died, so this process stops: %s: %s",
            hook.thread.name if hook.thread else "?",
            hook.exc_type.__name__,
            hook.exc_value,
            exc_info=(hook.exc_type, hook.exc_value, hook.exc_traceback),
        )
        _thread_died.set()
        _thread.interrupt_main(signal.SIGINT)

    threading.excepthook = died


def thread_died() -> bool:
    return _thread_died.is_set()


def service_main(
    name: str, parser: argparse.ArgumentParser, run, argv=None, interrupted: int = 130, prepare=None
) -> int:
    """The common start of a service: logging, its options, SIGTERM handled like Ctrl-C (the
    service saves, flushes or reports on its way out), a dead thread ends it, the session, then
    run(args, session)."""
    logging.basicConfig(level=logging.INFO, format=f"%(asctime)s {name} %(levelname)s %(message)s", stream=sys.stderr)
    # numba's OpenMP threads spin after each parallel kernel by default (about 3 ms), on the cores
    # that the other side of a lock-step tick needs next: sleeping made world + brain 1.4-1.6x
    # faster at A = 1,000-16,000 on 2 cores. Sleeping at once, though, each of a tick's back-to-back
    # kernels waits for its threads to wake: a spin of about 10 us (GNU OpenMP's count; others
    # ignore it) bridges them and no more, 1.2x faster again at A = 1,000 (docs/results.md).
    # Read when OpenMP loads, at the first kernel.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    os.environ.setdefault("GOMP_SPINCOUNT", "1000")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    guard_threads()
    if prepare is not None:
        prepare(args)
    session = open_session(args)
    try:
        code = run(args, session)
    except KeyboardInterrupt:
        code = interrupted
    return 1 if thread_died() else code


def wait_for_subscriber(outbox: Outbox, what: str, presence: Presence | None = None, every: float = 5.0) -> None:
    """Block until `outbox` has a subscriber (and `presence` is alive), logging every `every` s."""
    waited = 0.0
    while not ((presence is None or presence.wait(timeout=every)) and wait_until(lambda: outbox.matched, every)):
        waited += every
        log.info("waiting for %s to subscribe to %s (%.0f s)", what, outbox.key, waited)


def wait_until(predicate, timeout: float, interval: float = 0.001) -> bool:
    """Poll `predicate` until true or `timeout` seconds pass (for matching and start-up)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(interval)
    return True
