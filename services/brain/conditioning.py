"""Classical conditioning on the paper's building blocks (fig. 2 and fig. 4), as a demo.

`spikinglab conditioning` pairs a neutral stimulus a few ticks before the unconditioned one, over
and over, and shows the plastic weight grow until the neutral stimulus alone fires the motoneuron;
the reverse order, or a stimulus that comes after the response, is depressed instead.
"""

from __future__ import annotations

import argparse

import numpy as np

from .circuit import load_circuit
from .engine import Engine

TRIAL = 100  # ticks between trials: longer than the STDP windows, so trials do not interact


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
    probe = Engine(engine.circuit, training=False)
    probe.set_weights(engine.get_weights()[:1])
    feed = feed_for(probe, {stimulus: 0.0})
    target_index = engine.circuit.neuron_index(target)
    return any(probe.step(feed if k == 0 else None)[0, target_index] for k in range(50))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="spikinglab conditioning", description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=400)
    parser.add_argument("--a-plus", type=float, default=0.02, help="A+ = A- of the learning neurons")
    args = parser.parse_args(argv)

    def show(title, circuit_name, schedule, watch):
        circuit = load_circuit(circuit_name).with_learning_rate(args.a_plus)
        engine = Engine(circuit)
        before = {(stim, tgt): responds(engine, stim, tgt) for stim, tgt in watch}
        history = train(engine, schedule, args.trials)
        print(f"\n{title}  ({circuit.source}; trial schedule {schedule}, {args.trials} trials)")
        for stim, tgt in watch:
            syn = circuit.synapse_index(stim.removesuffix("_in").upper(), tgt)
            marks = [history[k][syn] for k in range(0, args.trials, max(1, args.trials // 8))]
            after = responds(engine, stim, tgt)
            print(f"  {circuit.synapse_label(syn):8s} weight 5.00 -> {history[-1][syn]:5.2f}  "
                  f"({' '.join(f'{m:.1f}' for m in marks)})   {stim} alone fires {tgt}: "
                  f"before {'yes' if before[(stim, tgt)] else 'no'}, after {'yes' if after else 'no'}")

    show("fig. 2, C paired 2 ticks before U", "conditioning", {"c_in": 0, "u_in": 2}, [("c_in", "M")])
    show("fig. 2, reverse order: U 2 ticks before C", "conditioning", {"u_in": 0, "c_in": 2}, [("c_in", "M")])
    show("fig. 4, A before U, B after", "association", {"a_in": 0, "u_in": 2, "b_in": 6},
         [("a_in", "M"), ("b_in", "M")])


if __name__ == "__main__":
    main()
