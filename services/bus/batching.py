"""Consecutive ticks kept together for one state message (BrainState, WorldState)."""

from __future__ import annotations

import numpy as np


def state_batch(agents: int) -> int:
    """Ticks per WorldState or BrainState message of a lock-step run: 250 for a few agents, whose
    messages are small (fewer of them cost the recorder less CPU on the cores the loop shares: the
    recorded 1-agent loop ran 5-6 % faster than at 50), down to 50 from 1,600 agents, so that no
    message holds more agent-ticks than a 1,600-agent one of 50 ticks did."""
    return max(50, min(250, 80_000 // agents))


class TickBatch:
    """Arrays of consecutive ticks, kept until there are `size` of them; `take()` gives the first
    tick and each array with a leading tick axis (for BrainState and WorldState). The buffers are
    made at the first add(), each [size, ...] of that array's shape and dtype, so a tick costs one
    copy per array (the recorded lock-step loop adds every tick)."""

    def __init__(self, size: int):
        self.size, self.count = size, 0
        self.first: int | None = None
        self.rows: dict[str, np.ndarray] = {}

    def add(self, tick: int, **arrays) -> None:
        if self.first is None:
            self.first = tick
        for name, value in arrays.items():
            rows = self.rows.get(name)
            if rows is None:
                value = np.asarray(value)
                rows = self.rows[name] = np.empty((self.size, *value.shape), value.dtype)
            rows[self.count] = value
        self.count += 1

    @property
    def full(self) -> bool:
        return self.count >= self.size

    def take(self) -> tuple[int | None, dict[str, np.ndarray]]:
        """The first tick (None when none was added) and the rows added; the batch starts afresh."""
        first, count = self.first, self.count
        self.first, self.count = None, 0
        return first, {name: rows[:count].copy() for name, rows in self.rows.items()}
