"""A thread that dies takes its process down, cleanly and loudly (services.runtime.guard_threads)."""

import subprocess
import sys
import textwrap

SERVICE = textwrap.dedent("""
    import logging, sys, threading, time
    from services.runtime import guard_threads, thread_died
    logging.basicConfig(level=logging.INFO)
    guard_threads()
    def motor_commands():
        time.sleep(0.2)
        raise IndexError("index 0 is out of bounds for axis 0 with size 0")
    threading.Thread(target=motor_commands, name="motor commands", daemon=True).start()
    try:
        while True:  # the main loop goes on as if nothing happened, until it is interrupted
            time.sleep(0.05)
    except KeyboardInterrupt:
        print("main loop ended: motors stopped", flush=True)
    sys.exit(1 if thread_died() else 0)
""")


def test_a_dead_thread_ends_the_process_with_its_reason():
    done = subprocess.run([sys.executable, "-c", SERVICE], capture_output=True, text=True, timeout=30)
    assert done.returncode == 1
    assert "main loop ended: motors stopped" in done.stdout  # the main thread's way out ran
    assert "thread 'motor commands' died, so this process stops: IndexError" in done.stderr
    assert "Traceback" in done.stderr  # where it died, for whoever mends it
