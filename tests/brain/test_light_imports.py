"""Commands that run in one process (`sweep`, `run --no-record`) and the brain's engine options
they share import neither the bus (zenoh) nor the viewer (rerun): each module imported alone, in a
fresh interpreter, and its sys.modules read."""

import json
import subprocess
import sys

import pytest

HEAVY = ("zenoh", "rerun")


def heavy_imports(module: str) -> list[str]:
    found = f"sorted({{name.split('.')[0] for name in sys.modules}} & {set(HEAVY)!r})"
    code = f"import json, sys, {module}\nprint(json.dumps({found}))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize(
    "module",
    [
        "services.brain.engine_options",
        "services.sweep",
        "services.run",
    ],
)
def test_imports_neither_zenoh_nor_rerun(module):
    assert heavy_imports(module) == []
