"""Ctrl-C never lands inside a numba compile (services/interrupts.py): it waits for the compile
under way, not for the next, then ends the process as Ctrl-C does, even one waiting in a sleep."""

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
