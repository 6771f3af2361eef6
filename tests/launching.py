"""Shipped launch files as tests run them: ports moved, the launcher started in a folder, and the
lines that say each file's services are at work."""

from __future__ import annotations

import subprocess
import sys
from typing import TextIO

from services.launch import shipped

from .processes import free_port

TICKING = r"\d[kMG]?tick/s"  # a progress bar's rate once ticks are done ("?tick/s" before the first)
READY = {  # patterns of lines that say a launch file's services are all up and at work
    "simulation": (TICKING, "recording group"),
    "sharded-simulation": (TICKING,),
    "sharded-worlds": (TICKING,),
    "secure-simulation": (TICKING, "recording group"),
    # the brain's first motor message: its kernels compiled (on a first run, before it joins the bus,
    # and a Ctrl-C meanwhile waits for the compile to end: docs/launch.md)
    "robot": ("first reading published", "a brain drives the robot", "recording group"),
    "secure-robot": ("first reading published", "a brain drives the robot", "recording group"),
    "remote-world": ("waiting for a brain", "recording group"),  # its world waits for a brain from elsewhere
    "remote-brain": ("brain ready on group",),  # it waits for a world from elsewhere
}


def launch_file(name: str, folder, **replace) -> str:
    """A shipped launch file with its ports moved to free ones (and any other text replaced)."""
    text = shipped()[name].read_text()
    for port in ("7447", "7448"):
        text = text.replace(port, str(replace.pop(port, free_port())))
    for old, new in replace.items():
        text = text.replace(old, new)
    path = folder / f"{name}.toml"
    path.write_text(text)
    return str(path)


def launch(folder, *args, stdout: int | TextIO = subprocess.PIPE) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "spikinglab", "launch", *map(str, args), "--no-colour"],
        cwd=folder,
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
    )
