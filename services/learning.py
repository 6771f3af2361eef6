"""How fast an insect learns: its learning time under several stated definitions, from the ticks it
spent on a noxious patch, and its collisions in the first and the last quarter of its run.

A "collision" here is a tick on a noxious patch: NetLogo's demo resets its error_free_counter in
every such tick, so an insect stuck on a wall is not collision-free.

The paper's Table 1 gives "the number of iterations before collision-free movement" without
saying how long movement must stay collision-free. Each definition here is one reading of it:

  free W      the tick of the last collision before the first W collision-free ticks
              (W = 5,000 is this project's default, set before any comparison with the paper;
              W = 35,000 is the NetLogo source's own rule for ending training:
              required_error_free_iterations)
  at most K in W   the tick of the last collision before the first window of W ticks that
              holds at most K collisions (a collision rate that fell below K per W ticks)

A learning time is None when the run ended before the definition was met. Medians and quartiles
count those as later than the run (a censored statistic: the median is a real tick only when
more than half the seeds got there).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

DEFINITIONS = {  # name -> (window W, collisions allowed in it)
    "free 1,000": (1_000, 0),
    "free 2,000": (2_000, 0),
    "free 5,000": (5_000, 0),
    "free 35,000 (NetLogo's stop rule)": (35_000, 0),
    "at most 2 in 5,000": (5_000, 2),
}
DEFAULT_DEFINITION = "free 5,000"
PAPER = {0.01: 19_000, 0.02: 15_000, 0.03: 9_000, 0.04: 7_000}  # Table 1: A+ = A- -> iterations


def noxious_ticks(
    world, brain, ticks: int, on_tick: Callable[[int], None] | None = None, device: str = "cpu"
) -> list[list[int]]:
    """Run world and brain in the closed loop for `ticks` ticks; the ticks each agent spent on a
    noxious patch (the pain sensor fed), from which every definition below is computed. `on_tick(t)`
    is called for every tick t; below PARALLEL_FROM agents, after each stretch of BIN ticks, which
    runs as one compiled call that keeps the pain sensor's ticks (1.7 times as fast for 16 agents);
    on the device ("cuda", services/gpu.py), after each launch."""
    from services.loop import check_loop, closed_loop, fused_loop
    from services.params import PARALLEL_FROM
    from services.world.world import BIN, PAIN

    check_loop(world, brain, ticks, on_tick)
    if device != "cpu":
        from services.gpu import check_device, fused_loop_cuda

        check_device(device)
        none = np.zeros(0, np.int64)
        kept: list[tuple[np.ndarray, np.ndarray]] = [(none, none)]  # (insects, ticks) of each launch, by tick

        def keep_rows(start: int, rows: np.ndarray) -> None:
            k, a = np.nonzero(rows)
            kept.append((a, start + k))
            if on_tick is not None:
                for t in range(start, start + len(rows)):
                    on_tick(t)

        fused_loop_cuda(world, brain, ticks, on_noxious=keep_rows)
        insects = np.concatenate([a for a, _ in kept])
        by_insect = np.argsort(insects, kind="stable")  # stable: each insect's ticks stay in order
        ends = np.searchsorted(insects[by_insect], np.arange(1, world.agents))
        return [t.tolist() for t in np.split(np.concatenate([t for _, t in kept])[by_insect], ends)]
    if brain.agents < PARALLEL_FROM:
        fed = np.zeros((ticks, world.agents), np.uint8)
        for start in range(0, ticks, BIN):
            stretch = range(start, min(start + BIN, ticks))
            fused_loop(world, brain, len(stretch), fed[stretch.start : stretch.stop])
            if on_tick is not None:  # the same calls as tick by tick, after the stretch
                for t in stretch:
                    on_tick(t)
        return [np.flatnonzero(fed[:, a]).tolist() for a in range(world.agents)]
    noxious = [[] for _ in range(world.agents)]

    def keep(t):
        for agent in np.flatnonzero(~np.isnan(world.sensors[:, PAIN])):
            noxious[agent].append(t)
        if on_tick is not None:
            on_tick(t)

    closed_loop(world, brain, ticks, keep)
    return noxious


def quarter_collisions(bins) -> tuple[np.ndarray, np.ndarray]:
    """Each agent's collisions in the first and in the last quarter of its run, from its collisions
    per bin, [agents, bins]. A quarter is a quarter of the bins, at least one: a run of fewer than
    four bins compares its first bin with its last."""
    bins = np.asarray(bins)
    q = max(bins.shape[1] // 4, 1)
    return bins[:, :q].sum(axis=1), bins[:, -q:].sum(axis=1)


def learning_time(collision_ticks, ticks: int, window: int, allowed: int = 0) -> int | None:
    """The tick of the last collision before the first `window` ticks that hold at most `allowed`
    collisions (0 when the run starts that way); None when no such window ended within `ticks`."""
    c = np.asarray(collision_ticks)
    if c.ndim != 1 or (c.size and not np.issubdtype(c.dtype, np.integer)):
        raise ValueError(f"collision_ticks must be a list of whole ticks, got {c.dtype} of shape {c.shape}")
    if window < 1 or allowed < 0:
        raise ValueError(f"window must be >= 1 and allowed >= 0, got window {window}, allowed {allowed}")
    c = c.astype(np.int64)
    if np.any(np.diff(c) < 0) or (c.size and (c[0] < 0 or c[-1] > ticks)):
        raise ValueError(f"collision_ticks must be sorted ticks in 0..{ticks}, got {c[:8].tolist()}...")
    # a window starts just after collision i (or after tick 0, as the world counts) and is met when
    # the (allowed + 1)-th collision after that start comes `window` or more ticks later, or never
    starts = np.concatenate([[1], c + 1])
    for i, start in enumerate(starts):
        k = i + allowed  # index of the (allowed + 1)-th collision at or after `start`
        end = c[k] if k < len(c) else ticks
        if end - start >= window:
            return int(start - 1) if i > 0 else 0
    return None


def stats(times: list[int | None], ticks: int) -> dict:
    """Median and quartiles (censored: None counts as later than `ticks`), and how many got there."""
    t = np.array([np.inf if x is None else x for x in times], dtype=float)
    q1, median, q3 = (float(np.quantile(t, q, method="inverted_cdf")) for q in (0.25, 0.5, 0.75))
    out = lambda x: None if np.isinf(x) else x  # noqa: E731
    return {
        "median": out(median),
        "q1": out(q1),
        "q3": out(q3),
        "reached": int(np.isfinite(t).sum()),
        "seeds": len(times),
        "ticks": ticks,
    }


def all_definitions(collision_ticks_per_agent: list, ticks: int) -> dict[str, dict]:
    """For every definition: each agent's learning time and their statistics."""
    out = {}
    for name, (window, allowed) in DEFINITIONS.items():
        times = [learning_time(c, ticks, window, allowed) for c in collision_ticks_per_agent]
        out[name] = {"times": times, **stats(times, ticks)}
    return out


def tick_text(x: float | None, ticks: int) -> str:
    return f"{x:,.0f}" if x is not None else f"> {ticks:,}"


def plot_table1(rows: list[dict], definition: str, path) -> None:
    """Learning time against A+ = A- per setting (median, quartiles) beside the paper's Table 1."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5), dpi=110)
    names = list(dict.fromkeys(r["name"] for r in rows))
    for k, name in enumerate(names):
        mine = [r for r in rows if r["name"] == name]
        x = np.array([r["a"] for r in mine]) * (1 + 0.03 * (k - len(names) / 2))  # spread the points apart
        ticks = mine[0]["ticks"]
        med = [r["definitions"][definition]["median"] or ticks * 1.05 for r in mine]
        lo = [r["definitions"][definition]["q1"] or ticks * 1.05 for r in mine]
        hi = [r["definitions"][definition]["q3"] or ticks * 1.05 for r in mine]
        ax.errorbar(
            x, med, yerr=[np.subtract(med, lo), np.subtract(hi, med)], marker="o", ms=4, capsize=3, lw=1, label=name
        )
    ax.plot(list(PAPER), list(PAPER.values()), "k*", ms=14, label="paper, Table 1")
    ax.axhline(rows[0]["ticks"], color="gray", ls=":", lw=1)
    ax.set(
        xlabel="A+ = A-",
        ylabel=f"learning time, ticks ({definition} collision-free)",
        yscale="log",
        title="Table 1 against the paper: median and quartiles over seeds (top line: end of run)",
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
