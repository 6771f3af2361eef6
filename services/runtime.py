"""How a service process starts and ends: logging, its options, signals, a thread that dies,
OpenMP's waiting threads, then its bus session and its run(config, session)."""

from __future__ import annotations

import _thread
import argparse
import ctypes
import logging
import os
import signal
import sys
import threading
import tracemalloc

from services.bus.config import BusConfigError, open_session
from services.bus.transport import close_session
from services.commands import PARENT
from services.interrupts import take_interrupts
from services.options import config_from

log = logging.getLogger("spikinglab")

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


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def end_with_parent() -> None:
    """A process that spawn() started ends, as on SIGTERM, when the one that started it dies, even
    by SIGKILL: no service runs on without its launcher, run or test (Linux's parent-death signal;
    elsewhere nothing changes). Its own children are watched by it, not by its parent."""
    parent = os.environ.pop(PARENT, None)
    if parent is None or not sys.platform.startswith("linux"):
        return
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != int(parent):  # it died before the signal was asked for
        os.kill(os.getpid(), signal.SIGTERM)


def process_main(name: str, parser: argparse.ArgumentParser, run, argv=None, interrupted: int = 130) -> int:
    """The common start of a process: logging, its options, SIGTERM handled like Ctrl-C (the
    process saves, flushes or reports on its way out), a dead thread ends it; then run(args).
    Ctrl-C (KeyboardInterrupt) ends it with `interrupted`; a dead thread with 1."""
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
    if getattr(args, "log_file", None):  # a service shown on the terminal as it is (world --log-file)
        copy = logging.FileHandler(args.log_file)
        copy.setFormatter(logging.getLogger().handlers[0].formatter)
        logging.getLogger().addHandler(copy)
    take_interrupts(signal.SIGTERM)
    guard_threads()
    try:
        end_with_parent()
        code = run(args)
    except KeyboardInterrupt:  # after what the process wrote on its way out; a router's or recorder's normal end
        if interrupted:
            log.warning("interrupted (Ctrl-C or SIGTERM): stopped")
        code = interrupted
    finally:
        if tracemalloc.is_tracing():  # PYTHONTRACEMALLOC=1: what of its memory Python objects hold
            log_python_heap()
    return 1 if thread_died() else code


def log_python_heap(sites: int = 5) -> None:
    """The Python heap at the process's end: the total traced, its peak and the files that
    allocated most of what is held (a growth of RSS that these do not show is native: Rerun's
    writer, Zenoh, the allocator)."""
    held, peak = tracemalloc.get_traced_memory()
    largest = tracemalloc.take_snapshot().statistics("filename")[:sites]
    log.info(
        "Python heap at the end: %.1f MB held (peak %.1f MB); most of it allocated in %s",
        held / 1e6,
        peak / 1e6,
        "; ".join(f"{stat.traceback[0].filename} {stat.size / 1e6:.1f} MB" for stat in largest),
    )


def service_main(
    name: str,
    parser: argparse.ArgumentParser,
    run,
    argv=None,
    interrupted: int = 130,
    prepare=None,
    mode: str | None = None,
    config: type | None = None,
) -> int:
    """A process on the bus: process_main, then its typed config (the dataclass `config`, made by
    config_from right after parsing; without: the options themselves), prepare(config) (work
    before the bus: checks that refuse to start), its bus session (`mode`: Zenoh's, "router" for a
    router; default: the options' choice), then run(config, session)."""

    def on_the_bus(args: argparse.Namespace) -> int:
        settings = args if config is None else config_from(args, config)
        if prepare is not None:
            prepare(settings)
        try:
            session = open_session(args, mode)
        except BusConfigError as e:
            raise SystemExit(str(e)) from None
        try:
            return run(settings, session)
        finally:  # on every way out (a refusal too): Zenoh's threads still calling into Python as
            close_session(session)  # it finalises make glibc abort the process ("exception not rethrown")

    return process_main(name, parser, on_the_bus, argv, interrupted)
