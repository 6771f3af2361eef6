"""Ctrl-C never lands inside a numba compile (services/interrupts.py): it waits for the compile
under way, not for the next, then ends the process as Ctrl-C does, even one waiting in a sleep. Nor
is it lost where Python drops what a weakref callback raises, nor raised in eval'd code, where it
would change the exit code the program chose."""

import os
import signal
import subprocess
import sys
import textwrap

from .processes import ROOT

CTRL_C_AS_A_KERNEL_COMPILES = textwrap.dedent(
    """
    import os, signal, time
    from numba import njit
    from numba.core import event
    from services.interrupts import take_interrupts

    class CtrlC(event.Listener):  # Ctrl-C as numba starts to compile the first kernel
        sent = False

        def on_start(self, data):
            if not self.sent:
                self.sent = True
                os.kill(os.getpid(), signal.SIGINT)

        def on_end(self, data):
            pass

    take_interrupts()
    event.register("numba:compile", CtrlC())
    kernels = [njit(lambda n: n * 2.5), njit(lambda n: n - 1.5), njit(lambda n: n / 3.5)]
    began = time.monotonic()
    try:
        for kernel in kernels:  # compiled one after another, as a first tick's are
            kernel(10)
        time.sleep(30)
    except KeyboardInterrupt:
        compiled = sum(len(kernel.overloads) for kernel in kernels)
        print(f"interrupted after {time.monotonic() - began:.1f} s with {compiled} kernel compiled")
    """
)


def test_ctrl_c_during_a_compile_waits_for_it_then_interrupts():
    done = subprocess.run(
        [sys.executable, "-c", CTRL_C_AS_A_KERNEL_COMPILES], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    said = done.stdout.split()
    assert said[:2] == ["interrupted", "after"] and float(said[2]) < 10  # not at the end of the sleep
    assert done.stdout.endswith("with 1 kernel compiled\n")  # that compile was not cut short, nor the next begun
    assert (
        done.stderr.count("interrupted: stopping once the kernel being compiled (or loaded from the cache) is ready")
        == 1
    )
    assert "Traceback" not in done.stderr


CTRL_C_IN_A_WEAKREF_CALLBACK = textwrap.dedent(
    """
    import os, signal, sys, time, weakref
    from services.interrupts import take_interrupts

    class Thing:
        pass

    def callback(ref):  # as an import's module lock has: Python prints and drops what it raises
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):  # the handler runs within these steps
            pass

    if sys.argv[1] == "taken":
        take_interrupts()
    thing = Thing()
    ref = weakref.ref(thing, callback)
    began = time.monotonic()
    try:
        del thing
        time.sleep(5)
        print("not interrupted")
    except KeyboardInterrupt:
        print(f"interrupted after {time.monotonic() - began:.1f} s")
    """
)


def test_ctrl_c_dropped_in_a_weakref_callback_is_taken_again():
    def run(handler):
        return subprocess.run(
            [sys.executable, "-c", CTRL_C_IN_A_WEAKREF_CALLBACK, handler],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )

    dropped = run("python's")  # the case it guards against: Python's own handler loses the Ctrl-C
    assert dropped.stdout == "not interrupted\n" and "Exception ignored in" in dropped.stderr
    taken = run("taken")
    said = taken.stdout.split()
    assert said[:2] == ["interrupted", "after"] and float(said[2]) < 2.5, taken.stdout + taken.stderr  # not at 5 s
    assert taken.stderr == ""


CTRL_C_IN_EVAL = textwrap.dedent(
    """
    import os, signal, sys, time
    from services.interrupts import take_interrupts

    if sys.argv[1] == "taken":
        take_interrupts()
    made = {"__name__": "made", "os": os, "signal": signal}  # as namedtuple's methods are made
    try:
        eval("os.kill(os.getpid(), signal.SIGINT) or sum(range(100_000))", made)
        time.sleep(5)
        print("not interrupted")
    except KeyboardInterrupt:
        print("interrupted")
    sys.exit(130)
    """
)


def test_ctrl_c_in_code_run_from_a_string_keeps_the_exit_code(tmp_path):
    """Run with -m, as `python -m spikinglab` and the services are: there CPython's mark of an
    interrupt raised in eval'd code decides the exit."""
    (tmp_path / "ctrl_c_in_eval.py").write_text(CTRL_C_IN_EVAL)

    def run(handler):
        return subprocess.run(
            [sys.executable, "-m", "ctrl_c_in_eval", handler],
            cwd=tmp_path,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            capture_output=True,
            text=True,
            timeout=60,
        )

    died = run("python's")  # the case it guards against: taken, and yet the process dies of SIGINT
    assert died.stdout == "interrupted\n" and died.returncode == -signal.SIGINT
    taken = run("taken")
    assert (taken.stdout, taken.returncode, taken.stderr) == ("interrupted\n", 130, "")


def test_ctrl_c_in_a_loop_is_noted_raised_only_in_a_wait_and_dropped_at_its_end():
    """ctrl_c_in_waits: Ctrl-C outside a wait is noted (the loop ends where it can) and raised as
    the next wait begins; inside one it is raised at once; the handlers are then put back."""
    from services.interrupts import ctrl_c_in_waits

    seen = []
    try:
        with ctrl_c_in_waits() as waits:
            for step in range(3):
                with waits:
                    pass
                os.kill(os.getpid(), signal.SIGINT)  # the handler runs before the next line
                seen.append((step, waits.came))
    except KeyboardInterrupt:
        seen.append("interrupted")
    assert seen == [(0, True), "interrupted"]
    try:
        with ctrl_c_in_waits() as waits, waits:
            os.kill(os.getpid(), signal.SIGINT)
            seen.append("not interrupted in a wait")
    except KeyboardInterrupt:
        seen.append("interrupted in a wait")
    assert seen[-1] == "interrupted in a wait"
    with ctrl_c_in_waits():
        os.kill(os.getpid(), signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
