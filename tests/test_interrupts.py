"""Ctrl-C never lands inside a numba compile (services/interrupts.py): it waits for the compile
under way, then ends the process as Ctrl-C does, even one waiting in a sleep."""

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

    class CtrlC(event.Listener):  # Ctrl-C as numba starts to compile
        def on_start(self, data):
            os.kill(os.getpid(), signal.SIGINT)

        def on_end(self, data):
            pass

    take_interrupts()
    event.register("numba:compile", CtrlC())
    kernel = njit(lambda n: n * 2.5)
    began = time.monotonic()
    try:
        kernel(10)
        time.sleep(30)
    except KeyboardInterrupt:
        print(f"interrupted after {time.monotonic() - began:.1f} s with {len(kernel.overloads)} kernel compiled")
    """
)


def test_ctrl_c_during_a_compile_waits_for_it_then_interrupts():
    done = subprocess.run(
        [sys.executable, "-c", CTRL_C_AS_A_KERNEL_COMPILES], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    said = done.stdout.split()
    assert said[:2] == ["interrupted", "after"] and float(said[2]) < 10  # not at the end of the sleep
    assert done.stdout.endswith("with 1 kernel compiled\n")  # the compile was not cut short
    assert "interrupted: stopping once the kernel being compiled is ready" in done.stderr
    assert "Traceback" not in done.stderr
