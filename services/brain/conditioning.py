"""Classical conditioning on the paper's building blocks (fig. 2 and fig. 4), as a demo.

`spikinglab conditioning` pairs a neutral stimulus a few ticks before the unconditioned one, over
and over, and shows the plastic weight grow until the neutral stimulus alone fires the motoneuron;
the reverse order, or a stimulus that comes after the response, is depressed instead. Writes
spike rasters before and after the pairing (the paper's fig. 2b and 4b) to OUT/fig2.png, fig4.png.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from services.options import Parser, at_least, output_folder, positive

from .circuit import load_circuit
from .engine import Engine

DESCRIPTION = "Classical conditioning on the paper's building blocks (fig. 2 and fig. 4), as a demo."
TRIAL = 100  # ticks between trials: longer than the STDP windows, so trials do not interact
# (title, circuit, schedule: input -> offset in ticks, (stimulus, target) pairs watched, figure or "")
DEMOS = (
    ("fig. 2, C paired 2 ticks before U", "conditioning", {"c_in": 0, "u_in": 2}, [("c_in", "M")], "fig2.png"),
    ("fig. 2, reverse order: U 2 ticks before C", "conditioning", {"u_in": 0, "c_in": 2}, [("c_in", "M")], ""),
    (
        "fig. 4, A before U, B after",
        "association",
        {"a_in": 0, "u_in": 2, "b_in": 6},
        [("a_in", "M"), ("b_in", "M")],
        "fig4.png",
    ),
)


def feed_for(engine: Engine, values: dict[str, float]) -> np.ndarray:
    """A feed array giving every agent the {input name: value} of `values`."""
    feed = engine.no_feed.copy()
    for name, value in values.items():
        feed[:, engine.circuit.input_index(name)] = value
    return feed


def train(engine: Engine, schedule: dict[str, int], trials: int, period: int = TRIAL) -> list[np.ndarray]:
    """Feed each input of `schedule` at its offset (ticks) in every trial; weights after each trial."""
    by_offset: dict[int, dict[str, float]] = {}
    for name, offset in schedule.items():
        by_offset.setdefault(10 + offset, {})[name] = 0.0
    feeds = {k: feed_for(engine, v) for k, v in by_offset.items()}
    history = []
    for _ in range(trials):
        for k in range(period):
            engine.step(feeds.get(k))
        history.append(engine.get_weights()[0])
    return history


def responds(engine: Engine, stimulus: str, target: str = "M") -> bool:
    """Does `stimulus` alone fire `target`? (A fresh state with the learned weights, training off.)"""
    spikes = raster(engine.circuit, engine.get_weights()[0], {0: {stimulus: 0.0}}, 50)
    return bool(spikes[:, engine.circuit.neuron_index(target)].any())


def raster(circuit, weights: np.ndarray, events: dict[int, dict[str, float]], ticks: int) -> np.ndarray:
    """Spikes [ticks, nodes] of a fresh network with `weights` (training off) fed {tick: {input: value}}."""
    probe = Engine(circuit, training=False)
    probe.set_weights(weights[None, :])
    feeds = {t: feed_for(probe, values) for t, values in events.items()}
    return np.array([probe.step(feeds.get(t))[0].copy() for t in range(ticks)])


def plot_rasters(
    path: Path, title: str, circuit, before: np.ndarray, after: np.ndarray, schedule: dict, probe: str
) -> None:
    """Two rasters side by side: a paired trial, then `probe` alone, with the weights before and after."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    events = {10 + offset: {name: 0.0} for name, offset in schedule.items()}
    events.setdefault(70, {})[probe] = 0.0
    names = circuit.node_names
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.2), dpi=110, sharey=True)
    for ax, weights, label in ((axes[0], before, "before pairing"), (axes[1], after, "after pairing")):
        spikes = raster(circuit, weights, events, 110)
        ax.eventplot(
            [np.flatnonzero(spikes[:, k]) for k in range(len(names))],
            lineoffsets=range(len(names)),
            linelengths=0.7,
            colors="k",
        )
        ax.axvspan(8, 30, color="tab:blue", alpha=0.08)
        ax.axvspan(68, 90, color="tab:orange", alpha=0.12)
        ax.set(title=f"{label}: paired trial | {probe} alone", xlabel="tick", xlim=(0, 110))
    axes[0].set_yticks(range(len(names)), names)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def show(
    title: str, circuit, schedule: dict[str, int], watch, trials: int, out: Path | None = None, figure: str = ""
) -> None:
    """Pair the inputs of `schedule` `trials` times on a fresh network of `circuit` and print, for
    each (stimulus, target) of `watch`, its synapse's weight before and after and whether the
    stimulus alone fires the target before and after; `figure`: the rasters to out/figure too."""
    engine = Engine(circuit)
    before = {(stim, tgt): responds(engine, stim, tgt) for stim, tgt in watch}
    initial = engine.get_weights()[0]
    history = train(engine, schedule, trials)
    if figure and out is not None:
        learning = circuit.neuron_types[circuit.neuron_index(watch[0][1])]
        title_line = f"{title}: {circuit.name} ({trials} pairings, A+ {learning.a_plus}, A- {learning.a_minus})"
        plot_rasters(out / figure, title_line, circuit, initial, history[-1], schedule, watch[0][0])
    print(f"\n{title}  ({circuit.source}; trial schedule {schedule}, {trials} trials)")
    for stim, tgt in watch:
        syn = circuit.synapse_index(stim.removesuffix("_in").upper(), tgt)
        marks = [history[k][syn] for k in range(0, trials, max(1, trials // 8))]
        after = responds(engine, stim, tgt)
        print(
            f"  {circuit.synapse_label(syn):8s} weight {initial[syn]:.2f} -> {history[-1][syn]:5.2f}  "
            f"({' '.join(f'{m:.1f}' for m in marks)})   {stim} alone fires {tgt}: "
            f"before {'yes' if before[(stim, tgt)] else 'no'}, after {'yes' if after else 'no'}"
        )


def main(argv=None) -> None:
    parser = Parser(prog="spikinglab conditioning", description=DESCRIPTION)
    parser.add_argument("--trials", type=at_least(1), default=400, help="pairings (default 400)")
    parser.add_argument("--a-plus", type=positive, default=0.02, help="A+ = A- of the learning neurons")
    parser.add_argument(
        "--out",
        type=output_folder,
        help="folder for the raster PNGs (default runs/conditioning-<date>)",
    )
    args = parser.parse_args(argv)
    out = args.out or Path("runs") / f"conditioning-{datetime.datetime.now():%Y%m%d-%H%M%S}"
    out.mkdir(parents=True, exist_ok=True)

    for title, name, schedule, watch, figure in DEMOS:
        show(title, load_circuit(name).with_learning_rate(args.a_plus), schedule, watch, args.trials, out, figure)
    print(f"\nspike rasters before and after pairing: {out}/fig2.png, {out}/fig4.png")


if __name__ == "__main__":
    main()
