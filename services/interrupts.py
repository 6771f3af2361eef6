"""Ctrl-C (and SIGTERM, where a process takes it as Ctrl-C) as KeyboardInterrupt, but never inside
a numba compile: raised there, it can land in a callback from LLVM, where Python prints and drops
it, and numba then fails with "RuntimeError: no compiled object yet" (a traceback and exit 1, not
the run ended at the ticks done). A signal that comes while the main thread compiles is raised as
that compile lets go of numba's compiler lock, before the next can take it (kernels compile
lazily, at their first call, one after another on a first tick, and mid-run too).

Nor is it raised where it would go astray, and an import can be in either place:
- in a weakref callback or a __del__ (an import's module lock has one), where Python drops it: it
  is taken again as that callback returns;
- in code that eval or exec runs from a string (namedtuple and dataclass make methods so), where
  CPython marks the process as ended by Ctrl-C even when the program takes the interrupt: run with
  -m (as the commands and services are), it would then die of SIGINT at its exit, not with the exit
  code it chose (130). It is raised once that code has returned."""

from __future__ import annotations

import _thread
import signal
import sys
import threading
import time
from contextlib import contextmanager

_pending = threading.Event()  # an interrupt waits for the compile under way to end
_listening = threading.Event()  # the listener below is registered with numba


def _compiler_lock():
    """numba's compiler lock, or None where numba is not loaded (then nothing compiles)."""
    return getattr(sys.modules.get("numba.core.compiler_lock"), "global_compiler_lock", None)


def _after_compile() -> None:
    """Called as numba's compiler lock is let go (numba's "numba:compiler_lock" event ends): the
    interrupt waiting is raised once the main thread's outermost compile is over."""
    lock = _compiler_lock()
    main = threading.current_thread() is threading.main_thread()
    if _pending.is_set() and main and lock is not None and not lock.is_locked():
        _pending.clear()
        raise KeyboardInterrupt


def _listen() -> None:
    from numba.core import event

    class CompileOver(event.Listener):
        def on_start(self, data) -> None:
            pass

        def on_end(self, data) -> None:
            _after_compile()

    event.register("numba:compiler_lock", CompileOver())
    _listening.set()


def on_interrupt(signum, frame) -> None:
    """The handler: KeyboardInterrupt now, a little later where it would go astray, or as the compile
    under way ends."""
    if _astray(frame):
        _later()
        return
    lock = _compiler_lock()
    if lock is None or not lock.is_locked():
        raise KeyboardInterrupt
    if not _listening.is_set():
        _listen()
    if not _pending.is_set():  # a second Ctrl-C meanwhile is the same interrupt
        _pending.set()
        print(
            "interrupted: stopping once the kernel being compiled (or loaded from the cache) is ready",
            file=sys.stderr,
            flush=True,
        )


def _take_again(unraisable) -> None:
    """sys.unraisablehook: a KeyboardInterrupt that Python dropped is taken again, once this hook
    and the callback have returned; anything else is reported as Python does."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and threading.current_thread() is threading.main_thread():
        _later()
    else:
        sys.__unraisablehook__(unraisable)


def _later() -> None:
    """Ctrl-C again, 1 ms on: SIGINT to this, the main thread, so that a sleep or wait here ends as
    well, sent by a thread this one does not wait for (a handler run now would go astray too)."""
    main = threading.get_ident()

    def send() -> None:
        time.sleep(0.001)
        signal.pthread_kill(main, signal.SIGINT)

    try:
        _thread.start_new_thread(send, ())
    except RuntimeError:  # the interpreter is shutting down: nothing is left to interrupt
        pass


def _astray(frame) -> bool:
    """Whether a KeyboardInterrupt raised in `frame` would go astray: in the hook above, or while
    eval or exec runs a string's top-level code (not a function that code made, called later; and
    not `python -c`'s own code, which is such a string too, run in __main__)."""
    while frame is not None:
        code = frame.f_code
        if code is _take_again.__code__:
            return True
        if (
            code.co_filename == "<string>"
            and code.co_name == "<module>"
            and frame.f_globals.get("__name__") != "__main__"
        ):
            return True
        frame = frame.f_back
    return False


def take_interrupts(*signals: int) -> None:
    """SIGINT, and each of `signals`, raise KeyboardInterrupt in the main thread, outside compiles."""
    for signum in (signal.SIGINT, *signals):
        signal.signal(signum, on_interrupt)
    sys.unraisablehook = _take_again


@contextmanager
def ctrl_c_held():
    """Ctrl-C (and SIGTERM, where it is taken as Ctrl-C) within the block raises KeyboardInterrupt at
    its end, not inside it. Main thread only, as every signal handler."""
    came: list[int] = []
    taken = [signum for signum in (signal.SIGINT, signal.SIGTERM) if callable(signal.getsignal(signum))]
    before = {signum: signal.signal(signum, lambda signum, frame: came.append(signum)) for signum in taken}
    try:
        yield
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)
    if came:
        raise KeyboardInterrupt


class Waits:
    """Ctrl-C (and SIGTERM, where it is taken as Ctrl-C) within ctrl_c_in_waits() is noted in
    `came`, for the loop to end where it can; it is raised at once only inside `with waits:` (a
    wait that loses nothing when cut), or as such a wait begins."""

    def __init__(self):
        self.open = False
        self.came = False

    def __enter__(self) -> Waits:
        if self.came:
            self.came = False
            raise KeyboardInterrupt
        self.open = True
        return self

    def __exit__(self, *exc) -> None:
        self.open = False


@contextmanager
def ctrl_c_in_waits():
    """A loop that must not be cut anywhere (a message taken from the bus and not yet kept is lost
    when KeyboardInterrupt is raised) notes Ctrl-C and ends by itself (Waits). Set once around the
    loop: a step costs it nothing."""
    waits = Waits()
    taken = [signum for signum in (signal.SIGINT, signal.SIGTERM) if callable(signal.getsignal(signum))]
    before = {signum: signal.getsignal(signum) for signum in taken}

    def handler(signum, frame) -> None:
        previous = before[signum]
        if waits.open and callable(previous):
            previous(signum, frame)
        else:
            waits.came = True

    for signum in taken:
        signal.signal(signum, handler)
    try:
        yield waits
    finally:
        for signum, previous in before.items():
            signal.signal(signum, previous)
