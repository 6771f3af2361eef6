"""The live view of `spikinglab run --view`: the recorder serves the run over gRPC, and the Rerun
viewer shows it: a window when there is a display, else the Rerun web viewer, whose page a
`rerun --serve-web` process hosts over HTTP. Both servers listen on one address, --view-host
(127.0.0.1 unless asked: this machine only)."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from services.recorder.service import free_port, viewer_answers, web_viewer_url
from services.recorder.viewer import viewer_command

log = logging.getLogger("spikinglab.run")
SHOWN_WITHIN_S = 60.0  # the viewer servers are up well within this (a few seconds here)
STOP_S = 5.0  # the web viewer's server ends within this of SIGTERM
LOOPBACK = "127.0.0.1"  # how this machine reaches a server on every interface
EVERY_INTERFACE = ("0.0.0.0", "::")


@dataclass
class LiveView:
    host: str  # the address the viewer servers listen on
    grpc_port: int  # the recorder's
    web_port: int | None  # the web viewer's; None: a viewer window shows the run
    web_server: subprocess.Popen | None = None

    @property
    def address(self) -> str:
        """Where this machine reaches the servers (every interface includes the loopback)."""
        host = LOOPBACK if self.host in EVERY_INTERFACE else self.host
        return f"[{host}]" if ":" in host else host  # IPv6, in a URL

    @property
    def source(self) -> str:
        return f"rerun+http://{self.address}:{self.grpc_port}/proxy"

    @property
    def page(self) -> str | None:
        return None if self.web_port is None else web_viewer_url(self.web_port, self.grpc_port, self.address)

    def recorder_options(self) -> dict:
        return {"serve": True, "grpc_host": self.host, "grpc_port": self.grpc_port}

    def start(self, log_file: Path) -> None:
        """Host the web viewer's page (a window needs nothing before the run is served)."""
        if self.web_port is None:
            return
        argv = [
            *rerun_command(),
            "--serve-web",
            "--bind",
            self.host,
            "--web-viewer-port",
            str(self.web_port),
            self.source,
        ]
        with open(log_file, "a") as out:  # a session of its own: it and the viewer it starts end together
            self.web_server = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)

    def show(self, running) -> None:
        """Once the recorder serves the run: open a viewer window on it (the user's: left open), or
        print the web viewer's address (printed earlier, it would refuse connections). `running()`
        says whether the run's services are all still going."""
        deadline = time.monotonic() + SHOWN_WITHIN_S
        while not (viewer_answers(self.source) and (self.page is None or viewer_answers(self.page))):
            if not running():
                return  # a service ended: the launcher says which
            if time.monotonic() > deadline:
                log.warning(
                    "no live view: the recorder does not serve the run (its log: recorder.log); the run goes on"
                )
                return
            time.sleep(0.2)
        if self.page is None:
            # its own server on a free port (--port auto) of this host: the recorder's may hold the default
            argv = [*rerun_command(), "--bind", self.host, "--port", "auto", self.source]
            subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
            log.info("live view: the Rerun viewer shows %s", self.source)
        else:
            log.info(
                "live view (no display here): open %s in a browser; it ends with the run, the recording stays",
                self.page,
            )

    def close(self) -> None:
        if self.web_server is not None and self.web_server.poll() is None:
            os.killpg(self.web_server.pid, signal.SIGTERM)  # the `rerun` script and the viewer binary it runs
            try:
                self.web_server.wait(STOP_S)
            except subprocess.TimeoutExpired:
                os.killpg(self.web_server.pid, signal.SIGKILL)
                self.web_server.wait()


def rerun_command() -> list[str]:
    """The Rerun viewer's command: the `rerun` of this install, else its module (rerun-sdk has both)."""
    return viewer_command() or [sys.executable, "-m", "rerun_cli"]


def live_view(host: str) -> LiveView:
    """A window when there is a display and a Rerun viewer, else the web viewer; their ports: the
    usual ones (9876, 9090) when free."""
    native = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) and viewer_command() is not None
    return LiveView(host, free_port(9876), None if native else free_port(9090))
