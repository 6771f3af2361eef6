"""The live view with a display: `spikinglab run --view` opens the Rerun viewer on the served run.

The display is Xvfb's (scripts/test.sh installs it). What is checked is what run decides and
starts: a viewer process on the run's address that connects to the recorder's server. Whether it
draws is the web-view test's part (this machine's software Vulkan paints nothing into Xvfb)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time

import psutil

from ..processes import live_run, running_with, wait_for_ticks


def free_display() -> int:
    return next(n for n in range(90, 200) if not os.path.exists(f"/tmp/.X11-unix/X{n}"))


def established(process: psutil.Process) -> set[int]:
    """The remote ports of the process's established TCP connections (none once it is gone)."""
    try:
        return {c.raddr.port for c in process.net_connections("tcp") if c.raddr and c.status == psutil.CONN_ESTABLISHED}
    except psutil.Error:
        return set()


def close(viewers) -> None:
    for viewer in viewers:
        try:
            viewer.kill()
        except psutil.Error:
            pass


def test_run_view_opens_the_rerun_viewer_on_a_display(tmp_path):
    xvfb = shutil.which("Xvfb")
    assert xvfb, "Xvfb is needed (scripts/test.sh installs it: apt-get install xvfb)"
    display = free_display()
    screen = subprocess.Popen(
        [xvfb, f":{display}", "-screen", "0", "1280x800x24"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    viewers, said = [], ""
    try:
        while not os.path.exists(f"/tmp/.X11-unix/X{display}"):
            assert screen.poll() is None, "Xvfb did not start"
            time.sleep(0.1)
        env = {**os.environ, "DISPLAY": f":{display}"}
        run, said = live_run(tmp_path, "native", env)
        try:
            assert "the Rerun viewer shows rerun+http://127.0.0.1:" in said, said
            source = said.split("viewer shows ", 1)[1].split()[0]
            port = int(source.split(":")[2].split("/")[0])
            deadline, connected = time.monotonic() + 60, False
            while time.monotonic() < deadline and not connected:
                viewers = [p for p in psutil.process_iter(["cmdline"]) if source in (p.info["cmdline"] or [])]
                connected = any(port in established(v) for v in viewers)
                time.sleep(0.5)
            assert connected, f"no viewer connected to {source}; viewer processes: {viewers}"
            wait_for_ticks(tmp_path / "native")  # Ctrl-C in a run under way, not one still compiling
            close(viewers)  # the window first: software rendering under Xvfb cannot keep up with the stream
        finally:
            run.send_signal(signal.SIGINT)
            said += run.communicate(timeout=120)[1]
        assert run.returncode == 130 and "Traceback" not in said, said
        assert (tmp_path / "native" / "recording.rrd").stat().st_size > 0
        assert not running_with(str(tmp_path))
    finally:
        close(viewers)  # the user's window is left open by run; the test closes it
        screen.kill()
        screen.wait()
