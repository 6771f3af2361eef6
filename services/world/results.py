"""What a run of the world reports: metrics.json, the log's line on the outcome, the progress bar,
and agent 0's path early and late in the run (trajectory.npz)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.vocabulary import BLACK, RED

from .world import World


def metrics_of(world: World, ticks: int, elapsed: float, resumed_at: int = 0) -> dict:
    m, p = world.metrics, world.params
    return {
        "ticks": ticks,
        "agents": world.agents,
        "seed": world.seed,
        "shared_arena": world.shared,
        "training": world.training,
        "elapsed_s": round(elapsed, 3),
        "ticks_per_s": round((ticks - resumed_at) / max(elapsed, 1e-9), 1),
        "resumed_at": resumed_at or None,  # the tick this process resumed the run at (its checkpoint)
        "world": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(p).items()},
        "collisions_per_1000_ticks": np.array(m.bins).T.tolist() if m.bins else [[] for _ in range(world.agents)],
        "collisions": m.collisions.tolist(),
        "collisions_by_colour": {c: m.collisions_by_colour[:, k].tolist() for k, c in ((BLACK, "black"), (RED, "red"))},
        "food": m.food.tolist(),
        "distance": np.round(m.distance, 3).tolist(),
        "resets": m.resets.tolist(),
        "ticks_since_last_collision": [ticks - int(t) if t >= 0 else ticks for t in m.last_collision],
        "learning_time": [int(t) if t >= 0 else None for t in m.learned_at],
        "learning_time_definition": f"the last tick on a noxious patch before the first {p.learned_after} "
        "ticks off them (null: not reached)",
    }


def outcome(result: dict, shown: int = 8) -> str:
    """The log's one line on what the insects did: each one's for a few, a summary for a population."""
    collisions, learned = result["collisions"], result["learning_time"]
    if len(collisions) <= shown:
        return f"collisions {collisions}; learning time {learned}"
    reached = sum(t is not None for t in learned)
    return (
        f"{len(collisions)} insects: collisions {np.mean(collisions):.1f} per insect on average (the first "
        f"{shown}: {collisions[:shown]}); learned: {reached} of {len(learned)}"
    )


class Progress:
    """A progress bar with ticks/s, collisions per 1,000 ticks and food (tqdm, on stderr)."""

    def __init__(self, world: World, ticks: int, enabled: bool):
        self.world, self.bar = world, None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(
                total=ticks, initial=world.tick, unit="tick", unit_scale=True, dynamic_ncols=True, mininterval=0.5
            )
        self._shown = world.tick  # a resumed run starts there

    def update(self, tick: int) -> None:
        if self.bar is None or tick - self._shown < 500:
            return
        m = self.world.metrics
        recent = m.bins[-1].mean() if m.bins else m.collisions.mean() * 1000 / max(tick, 1)
        self.bar.set_postfix_str(f"collisions/1k {recent:.1f}, food {m.food.mean():.0f}", refresh=False)
        self._show(lambda bar: bar.update(tick - self._shown))
        self._shown = tick

    def close(self, tick: int) -> None:
        self._show(lambda bar: (bar.update(tick - self._shown), bar.close()))

    def _show(self, draw) -> None:
        """Draw on the bar; where its terminal is gone (a launcher killed: the pipe it read closed),
        the run goes on without one, so that it still writes its result."""
        if self.bar is None:
            return
        try:
            draw(self.bar)
        except OSError:
            self.bar.disable = True  # its close, at exit, would write again
            self.bar = None


class Trajectory:
    """Agent 0's path over the first and the last TICKS ticks, and the map at both times
    (trajectory.png, the paper's fig. 8: short paths early in training, long ones late)."""

    TICKS = 5000

    def __init__(self, world: World, ticks: int):
        self.world, self.n = world, min(self.TICKS, ticks)
        self.early, self.late = np.full((self.n, 2), np.nan), np.full((self.n, 2), np.nan)
        self.grid_early = world.grid[world.arena_of[0]].copy()

    def keep(self, t: int) -> None:
        if t < self.n:
            self.early[t] = self.world.pos[0]
        self.late[t % self.n] = self.world.pos[0]

    def arrays(self) -> dict[str, np.ndarray]:
        """What a checkpoint keeps of the path (restored in place by snapshots.copy_into)."""
        return {"early": self.early, "late": self.late, "grid_early": self.grid_early}

    def save(self, path: Path, ticks: int) -> None:
        late = np.roll(self.late, -(ticks % self.n), axis=0)  # oldest first
        np.savez_compressed(
            path,
            early=self.early,
            late=late,
            late_from=ticks - self.n,
            grid_early=self.grid_early,
            grid_late=self.world.grid[self.world.arena_of[0]],
            x_min=self.world.params.x_min,
            y_min=self.world.params.y_min,
        )
