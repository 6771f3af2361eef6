"""Every test gets one or more of the markers registered in pyproject.toml, decided here from its
source (its own, that of the fixtures it uses and that of the module's functions it calls), so that
no test file has to say it: `pytest -m unit` is the quick in-process part, `-m "not (realtime or
viewer)"` the part that a loaded machine cannot upset (scripts/test.sh runs it on every core, then
the rest alone).

  process:  starts processes (services, a run, pip)
  realtime: its outcome depends on wall-clock timing: the free-running brain (--clock), the
            gateway (its safety stops and motor timeout), the simulated robot, a quiet time; a
            shipped launch file that runs one of these, named in the test or a parameter of it
  viewer:   needs a browser, a display or a Vulkan driver; skipped with the reason where the system
            lacks them, failed instead under CI (scripts/test.sh installs them there)
  unit:     none of these
"""

from __future__ import annotations

import ctypes.util
import inspect
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from functools import cache
from pathlib import Path

import pytest

from services.launch import shipped

from .warm_up import SIZES

PROCESS = re.compile(r"(?<![\w.])(start|spawn)\(|\bsubprocess\.|\bPopen\(|\bLauncher\(|\bsys\.executable\b")
REALTIME = re.compile(
    r'"--clock"|(?<![\w.])start\(\s*"gateway"|"spikinglab", "gateway", "--listen"'
    r"|\bgateway_and_brain\(|\bSimBackend\(|\bquiet_s=|assert .*\bmonotonic\(\) -"
)
LAUNCHED = re.compile(r'\blaunch_file\(\s*"([\w-]+)"')  # a shipped launch file named in a test


@cache
def realtime_launch_files() -> frozenset[str]:
    """The shipped launch files that run a gateway or a free-running brain."""

    def realtime(table: str, options: dict) -> bool:
        return options.get("service", table) == "gateway" or "clock" in options

    files = {name: tomllib.loads(path.read_text()) for name, path in shipped().items()}
    return frozenset(name for name, data in files.items() if any(realtime(t, o) for t, o in data.items()))


def runs_in_realtime(item: pytest.Function, source: str) -> bool:
    params = getattr(item, "callspec", None)
    named = {*LAUNCHED.findall(source), *(v for v in (params.params.values() if params else ()) if isinstance(v, str))}
    return bool(REALTIME.search(source) or named & realtime_launch_files())


# what a viewer test runs, and the system package it needs for that
VIEWERS = {
    re.compile(r"\bsync_playwright\b"): "chromium",
    re.compile(r"\bXvfb\b"): "Xvfb",
    re.compile(r'"screenshot",'): "a Vulkan driver",
}


def has_vulkan() -> bool:
    icds = [p for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d") for p in Path(d).glob("*.json")]
    return bool(icds) and ctypes.util.find_library("vulkan") is not None


PRESENT = {
    "chromium": lambda: shutil.which("chromium"),
    "Xvfb": lambda: shutil.which("Xvfb"),
    "a Vulkan driver": has_vulkan,
}
NEEDS = pytest.StashKey[list[str]]()  # what a viewer test needs, kept from collection to its setup
INSTALL = {"chromium": "chromium", "Xvfb": "xvfb", "a Vulkan driver": "libvulkan1 mesa-vulkan-drivers"}


@cache
def module_functions(module) -> dict[str, str]:
    """The source of each function (fixtures included) defined in a test module."""
    functions = {name: inspect.unwrap(f) for name, f in vars(module).items() if callable(f)}  # a fixture wraps its
    return {
        name: inspect.getsource(f)
        for name, f in functions.items()
        if inspect.isfunction(f) and getattr(f, "__module__", None) == module.__name__
    }


def reached_source(item: pytest.Function) -> str:
    """The test's source with that of the module's functions it reaches (by name, transitively) and
    of the fixtures it uses that the module defines."""
    functions = module_functions(item.module)
    own = inspect.getsource(item.function)
    seen, todo = set(), [*item.fixturenames, *(name for name in functions if re.search(rf"\b{name}\b", own))]
    while todo:
        name = todo.pop()
        if name in seen or name not in functions:
            continue
        seen.add(name)
        todo += [other for other in functions if other not in seen and re.search(rf"\b{other}\b", functions[name])]
    return "\n".join([own, *(functions[name] for name in seen)])


def pytest_sessionstart(session: pytest.Session) -> None:
    """The kernel cache warmed before any test (tests/warm_up.py), once: by pytest-xdist's
    controller before it starts its workers, not by each worker."""
    config = session.config
    if hasattr(config, "workerinput") or config.option.collectonly:
        return
    terminal = config.pluginmanager.get_plugin("terminalreporter")
    say = terminal.write_line if terminal else print
    say("compiling the services' kernels into the kernel cache (minutes where it is empty: python -m tests.warm_up)")
    started = time.monotonic()
    root = Path(__file__).parent.parent
    command = [sys.executable, "-m", "tests.warm_up"]
    warming = [subprocess.Popen([*command, str(n)], cwd=root, stderr=subprocess.PIPE, text=True) for n in SIZES]
    for process in warming:
        err = process.communicate()[1].strip()
        if process.returncode:  # the tests that compile the kernels fail too, and say more
            say(f"the kernels' warm-up failed: {err.splitlines()[-1] if err else f'exit {process.returncode}'}")
    say(f"kernels ready in {time.monotonic() - started:.1f} s")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if not isinstance(item, pytest.Function):
            continue
        source = reached_source(item)
        needs = sorted({need for pattern, need in VIEWERS.items() if pattern.search(source)})
        kinds = [
            name
            for name, found in (
                ("process", PROCESS.search(source)),
                ("realtime", runs_in_realtime(item, source)),
                ("viewer", needs),
            )
            if found
        ]
        for name in kinds or ["unit"]:
            item.add_marker(name)
        item.stash[NEEDS] = needs


def pytest_runtest_setup(item: pytest.Item) -> None:
    missing = [need for need in item.stash.get(NEEDS, []) if not PRESENT[need]()]
    if missing:
        packages = " ".join(INSTALL[need] for need in missing)
        why = f"needs {', '.join(missing)} (scripts/test.sh installs it: apt-get install {packages})"
        if os.environ.get("CI"):
            pytest.fail(f"{why}; under CI this is a failure, not a skip")
        pytest.skip(why)
