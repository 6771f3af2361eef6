"""spikinglab's benchmarks: `spikinglab bench NAME`, each printing its figures as JSON on its last line."""

import json
from pathlib import Path


def steady_rate(folder: Path) -> float:
    """Ticks/s of a lock-step run after its first tick, from the world's metrics.json in `folder`:
    the first round trip holds the brain's start, which the in-process and ping-pong figures leave
    out as a warm-up too."""
    return json.loads((folder / "metrics.json").read_text())["steady_ticks_per_s"]
