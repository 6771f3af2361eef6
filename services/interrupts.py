"""Ctrl-C (and SIGTERM, where a process takes it as Ctrl-C) as KeyboardInterrupt, but never inside
a numba compile: raised there, it can land in a callback from LLVM, where Python prints and drops
it, and numba then fails with "RuntimeError: no compiled object yet" (a traceback and exit 1, not
the run ended at the ticks done). A signal that comes while this thread compiles is raised as soon
as that compile is over (kernels compile lazily, at their first call, so mid-run too)."""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager

_pending = threading.Event()  # an interrupt waits for a compile to end


def _after_compile(lock, signum: int) -> None:
    with lock:  # numba's compiler lock: free once the main thread's compile is over
        pass
    _pending.clear()
    signal.pthread_kill(threading.main_thread().ident or 0, signum)  # a signal, to wake a main thread that waits


def on_interrupt(signum, frame) -> None:
    """The handler: KeyboardInterrupt now, or once the compile under way is over."""
    compiler = sys.modules.get("numba.core.compiler_lock")  # not imported: nothing compiles
    lock = getattr(compiler, "global_compiler_lock", None)
    if lock is None or not lock.is_locked():
        raise KeyboardInterrupt
    if not _pending.is_set():  # a second Ctrl-C meanwhile is the same interrupt
        _pending.set()
        print("interrupted: stopping once the kernel being compiled is ready", file=sys.stderr, flush=True)
        threading.Thread(target=_after_compile, args=(lock, signum), name="interrupt", daemon=True).start()


def take_interrupts(*signals: int) -> None:
    """SIGINT, and each of `signals`, raise KeyboardInterrupt in the main thread, outside compiles."""
    for signum in (signal.SIGINT, *signals):
        signal.signal(signum, on_interrupt)


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
