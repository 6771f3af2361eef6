"""Messages on the bus: strict inboxes, outboxes, liveliness, one service's place on the bus.

Zenoh's subscribers, publishers and liveliness are used here (and in pingpong.py's probe);
config.py opens the sessions. A message is decoded strictly on arrival (bus/schemas.py); what
does not decode is counted and logged by key and reason, never used.
"""

from __future__ import annotations

import collections
import logging
import os
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable

import zenoh

from . import keys
from .config import zenoh_says
from .schemas import BusError, Message, decode, encode

log = logging.getLogger("spikinglab.bus")

QUIET_S = 2.0  # another run may take over a brain or a recording only once the run served has been silent
# this long (its world re-sends every second while it lives), so a message of another run cannot take a live one
DROPPED = "dropped, backlog full"  # the reason counted for messages a Backlog dropped
REASONS_KEPT = 32  # distinct rejection reasons counted per key; the rest as "other reasons"


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

    def try_recv(self) -> zenoh.Sample | None:
        with self._ready:
            return self._pop() if self._items else None

    def recv(self) -> zenoh.Sample:
        with self._ready:
            self._ready.wait_for(lambda: self._items)
            return self._pop()

    def _pop(self) -> zenoh.Sample:
        """The oldest sample; the caller holds the lock and has seen one waiting."""
        sample = self._items.popleft()
        self.size -= len(sample.payload)
        return sample


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
        self._channel: Backlog | zenoh.Subscriber[zenoh.Handler[zenoh.Sample]]
        if self._backlog:
            self._sub = session.declare_subscriber(key, self._backlog)
            self._channel = self._backlog
        else:
            self._sub = self._channel = session.declare_subscriber(key, zenoh.handlers.FifoChannel(capacity))
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
        with self._changed:  # with seen_from_now's: a token's arrival is never lost between the two
            self.seen = self.seen or up
            (self._alive.add if up else self._alive.discard)(key)
            self._changed.notify_all()
        if self._on_change is not None:
            self._on_change("up" if up else "down", key)
        else:
            self.events.put(("up" if up else "down", key))

    @property
    def alive(self) -> bool:
        return bool(self._alive)

    def seen_from_now(self) -> None:
        """`seen` from here on says whether one has been alive since this call (a new run's watch)."""
        with self._changed:
            self.seen = bool(self._alive)

    def wait_seen(self, timeout: float) -> bool:
        """Wait until one has been alive since the watch began (or seen_from_now); True if so."""
        with self._changed:
            return self._changed.wait_for(lambda: self.seen, timeout)

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until at least one is alive; True if so."""
        with self._changed:
            return self._changed.wait_for(lambda: bool(self._alive), timeout)

    def first(self, which: Callable[[str], bool], timeout: float | None = None) -> str | None:
        """Wait until a service whose name `which` accepts is alive (a watch of "*"); its name, or None."""
        found: list[str] = []

        def seen() -> bool:
            found[:] = [name for name in (key.rsplit("/", 1)[-1] for key in self._alive) if which(name)]
            return bool(found)

        with self._changed:
            self._changed.wait_for(seen, timeout)
        return min(found) if found else None

    def close(self) -> None:
        self._sub.undeclare()


def close_session(session: zenoh.Session) -> None:
    """Close a session, once. A peer that no longer answers (a frozen process) is said, not raised:
    the work is done."""
    if session.is_closed():
        return
    try:
        session.close()
    except zenoh.ZError as e:
        log.warning("the bus session did not close cleanly (%s): a peer does not answer", zenoh_says(e))


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

        leaving: set[str] = set()  # services that said they leave of their own accord

        def on_change(change: str, key: str) -> None:
            service = key.rsplit("/", 1)[-1]
            if service == self.service or keys.WAITING in service:  # one waiting is said when it joins
                return
            if service.endswith(keys.LEAVING):
                if change == "up":
                    leaving.add(service.removesuffix(keys.LEAVING))
                return
            try:
                context = where()
            except Exception:  # a context is a courtesy: never a reason to miss the news
                context = ""
            if change == "down" and service.endswith(keys.DONE):  # a shard's "finished" token, dropped as the run ends
                log.info("the %s token is dropped%s", service, context)
            elif change == "down":  # an orderly end is news; a process killed or lost, a warning
                orderly = service in leaving
                leaving.discard(service)
                log.log(logging.INFO if orderly else logging.WARNING, "the %s left the bus%s", service, context)
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
        try:  # said before its token goes, on the same session: the others see the two in that order
            leaving = self.session.liveliness().declare_token(keys.alive(self.group, self.service + keys.LEAVING))
        except zenoh.ZError:  # the session already gone
            leaving = None
        self._token.undeclare()
        close_session(self.session)  # and with it `leaving`
        del leaving


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
