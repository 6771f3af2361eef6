"""Engine benchmark: the insect circuit, random sensor input, training on.

single: ticks/s of one agent through Engine.step(feed), the per-tick call a closed loop makes,
        and through Engine.run(feeds), all ticks in one compiled call (as Brian2's standalone mode
        runs a whole simulation in C++).
batch:  agent-ticks/s of A = 1000 agents stepped together.
Both for each semantics (phased, netlogo with its random order), on the same feeds.
--calls: where one agent's phased step() goes, in ns per call (docs/tick.md, "Layout and speed").
--orders: what bounds the netlogo engine at A = 1000: its random order, its file order and the
        phased engine in turns, agent-ticks/s and spikes per agent-tick of each.
--evaluate: agent-ticks/s of `evaluate` (the closed loop, world and default engine) for --insects
        insects of one setting (A+ = A- = 0.04) over --evaluate-ticks ticks, set-up included.
The last line printed is JSON. Run: `spikinglab bench engine` or `python -m spikinglab.bench.engine`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np
from numba import njit, typeof

from services.brain.circuit import load_circuit
from services.brain.engine import FEED_TYPE, SEMANTICS, Engine
from services.kernels import compiled
from services.options import Parser, at_least
from spikinglab.bench.feeds import random_feeds


def best_rate(engine, feeds, repeats, agents=1):
    """Best of `repeats` passes over `feeds` in agent-ticks per second (first pass warms up)."""
    step = engine.step
    rates = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        for f in feeds:
            step(f)
        rates.append(len(feeds) * agents / (time.perf_counter() - t0))
    return max(rates[1:])


def best_run_rate(engine, feeds, repeats):
    """Best of `repeats` run() calls over all of `feeds`, one agent, in ticks per second."""
    rates = []
    for _ in range(repeats + 1):  # the first compiles or loads the runner
        t0 = time.perf_counter()
        engine.run(feeds)
        rates.append(len(feeds) / (time.perf_counter() - t0))
    return max(rates[1:])


@njit
def _noop_structures(feed, network, state):
    pass


def noop_of(arity: int):
    """A compiled no-op of `arity` arguments, each unboxed at every call (numba compiles a *args
    function for one tuple, which would be unboxed as one)."""
    names = ", ".join(f"a{i}" for i in range(arity))
    scope: dict = {}
    exec(f"def noop({names}):\n    pass\n", scope)
    return njit(scope["noop"])


def call_costs(circuit, calls: int, repeats: int) -> dict:
    """ns per call, best of `repeats` passes of `calls`: one agent's phased step() (the feed's
    check, then the compiled tick), the compiled tick alone, a compiled no-op given the tick's
    arguments (the feed and the two structures) and one given the same arrays one by one, as the
    kernels took them before they took structures (the feed, the network's and the state's fields)."""
    engine = Engine(circuit, semantics="phased")
    feed = np.full(engine.no_feed.shape, np.nan)
    network, state = engine.network, engine.state
    arrays = (feed, *(getattr(network, f) for f in network.__dataclass_fields__))
    arrays += tuple(getattr(state, f) for f in state.__dataclass_fields__)
    structures = (feed, *engine.structs)
    noop_structures = compiled(_noop_structures, (FEED_TYPE, *(typeof(s) for s in engine.structs)))
    noop_arrays = compiled(noop_of(len(arrays)), tuple(typeof(a) for a in arrays))
    cases = {
        "step": (engine.step, (feed,)),
        "tick": (engine._tick, structures),
        "no-op, 2 structures": (noop_structures, structures),
        f"no-op, {len(arrays) - 1} arrays": (noop_arrays, arrays),
    }
    costs = {}
    for name, (call, args) in cases.items():
        best = math.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(calls):
                call(*args)
            best = min(best, time.perf_counter() - t0)
        costs[name] = round(best / calls * 1e9)
        print(f"{name}: {costs[name]} ns per call")
    return costs


def order_split(circuit, agents: int, ticks: int, rounds: int) -> dict:
    """Median agent-ticks/s of the netlogo engine with its random order and with file order, and of
    the phased engine, measured in turns on the same feeds, with each one's spikes per agent-tick:
    file order against phased is the turn-by-turn loop's cost at about the same activity, random
    against file order what the order changes (the turns' own work, and the activity it makes)."""
    feeds = random_feeds(np.random.default_rng(0), circuit, ticks, agents)
    cases = {
        "netlogo, random order": Engine(circuit, agents=agents, semantics="netlogo", order="random"),
        "netlogo, random order, turns one by one": Engine(circuit, agents=agents, order="random", by_receiver=False),
        "netlogo, file order": Engine(circuit, agents=agents, semantics="netlogo", order="file"),
        "phased": Engine(circuit, agents=agents, semantics="phased"),
    }
    rates: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(rounds):
        for name, engine in cases.items():
            engine.reset()
            rates[name].append(best_rate(engine, feeds, 1, agents=agents))
    result = {}
    for name, engine in cases.items():
        engine.reset()
        spikes = float(engine.run(feeds).sum()) / agents / ticks
        rate = float(np.median(rates[name]))
        print(
            f"{name}: A = {agents} {rate:,.0f} agent-ticks/s (median of {rounds}), {spikes:.2f} spikes per agent-tick"
        )
        key = name.replace(",", "").replace(" ", "_")
        result |= {f"{key}_agent_ticks_per_s": round(rate), f"{key}_spikes_per_agent_tick": round(spikes, 3)}
    return result


def evaluate_rate(insects: int, ticks: int) -> dict:
    """Wall-clock agent-ticks/s of one `evaluate` call (its kernels loaded or compiled first)."""
    from services.loop import evaluate

    settings = {"a_plus": [0.04], "a_minus": [0.04]}
    evaluate(settings, 10, range(insects))  # compile or load the kernels
    t0 = time.perf_counter()
    evaluate(settings, ticks, range(insects))
    seconds = time.perf_counter() - t0
    rate = insects * ticks / seconds
    print(f"evaluate: {insects:,} insects x {ticks:,} ticks in {seconds:.2f} s: {rate:,.0f} agent-ticks/s")
    return {f"evaluate{insects}_agent_ticks_per_s": round(rate)}


def parser() -> Parser:
    p = Parser(prog="spikinglab bench engine", description=(__doc__ or "").splitlines()[0])
    p.add_argument(
        "--ticks",
        type=at_least(1),
        help="ticks per pass for one agent; calls with --calls (default 200,000)",
    )
    # each option without a default here, as it serves some of the modes only (main's mode_defaults)
    p.add_argument("--agents", type=at_least(1), help="agents in the batch case (default 1,000)")
    p.add_argument("--batch-ticks", type=at_least(1), help="ticks per pass in the batch case (default 500)")
    p.add_argument("--repeats", type=at_least(1), help="passes of each case, the best reported (default 3)")
    p.add_argument("--rounds", type=at_least(1), help="rounds of the two batch engines in turns (ratio; default 20)")
    only = p.add_mutually_exclusive_group()
    only.add_argument("--calls", action="store_true", help="only where one agent's step() goes, per call")
    only.add_argument("--orders", action="store_true", help="only the netlogo engine's orders against phased, in turns")
    only.add_argument("--evaluate", action="store_true", help="only evaluate()'s agent-ticks/s")
    p.add_argument("--insects", type=at_least(1), help="insects in the --evaluate case (default 1,024)")
    p.add_argument("--evaluate-ticks", type=at_least(1), help="ticks in the --evaluate case (default 20,000)")
    return p


def arguments(argv=None) -> argparse.Namespace:
    """The options, each left out given the default of the case it serves; one given to a case it
    does not serve is refused."""
    p = parser()
    args = p.parse_args(argv)
    mode = next((f"--{m}" for m in ("calls", "orders", "evaluate") if getattr(args, m)), "")
    p.mode_defaults(
        args,
        mode,
        {
            "--ticks": (200_000, ("", "--calls")),
            "--agents": (1000, ("", "--orders")),
            "--batch-ticks": (500, ("", "--orders")),
            "--repeats": (3, ("", "--calls")),
            "--rounds": (20, ("", "--orders")),
            "--insects": (1024, ("--evaluate",)),
            "--evaluate-ticks": (20_000, ("--evaluate",)),
        },
    )
    return args


def main(argv=None) -> dict:
    args = arguments(argv)
    if args.evaluate:
        result = evaluate_rate(args.insects, args.evaluate_ticks)
        print(json.dumps(result))
        return result

    circuit = load_circuit("insect").with_learning_rate(0.04)
    if args.calls:
        result = call_costs(circuit, args.ticks, args.repeats)
        print(json.dumps(result))
        return result
    if args.orders:
        result = order_split(circuit, args.agents, args.batch_ticks, args.rounds)
        print(json.dumps(result))
        return result
    result, batches = {}, {}
    for semantics in SEMANTICS:
        rng = np.random.default_rng(0)
        t0 = time.perf_counter()
        single = Engine(circuit, semantics=semantics)
        single.step()
        batch = Engine(circuit, agents=args.agents, semantics=semantics)
        batch.step()
        print(f"{semantics}: compile/load {time.perf_counter() - t0:.2f} s (cached after the first run)")

        feeds = random_feeds(rng, circuit, args.ticks, 1)
        single_rate = best_rate(single, feeds, args.repeats)
        print(f"{semantics}: single agent {single_rate:,.0f} ticks/s ({1e6 / single_rate:.2f} us per step)")
        run_rate = best_run_rate(single, feeds, args.repeats)
        print(f"{semantics}: single agent, {args.ticks:,} ticks in one run() call: {run_rate:,.0f} ticks/s")

        feeds = random_feeds(rng, circuit, args.batch_ticks, args.agents)
        batch_rate = best_rate(batch, feeds, args.repeats, agents=args.agents)
        counted = feeds[:100]
        spikes = int(batch.run(counted).sum())
        print(
            f"{semantics}: A = {args.agents} {batch_rate:,.0f} agent-ticks/s on {os.cpu_count()} cores "
            f"({spikes / args.agents / len(counted):.2f} spikes per agent per tick; training on)"
        )
        prefix = "" if semantics == "phased" else f"{semantics}_"
        result[f"{prefix}single_ticks_per_s"] = round(single_rate)
        result[f"{prefix}single_run_ticks_per_s"] = round(run_rate)
        result[f"{prefix}batch{args.agents}_agent_ticks_per_s"] = round(batch_rate)
        batches[semantics] = (batch, feeds)
    ratio = result[f"netlogo_batch{args.agents}_agent_ticks_per_s"] / result[f"batch{args.agents}_agent_ticks_per_s"]
    print(f"netlogo / phased at A = {args.agents}: {ratio:.2f} (best passes, one engine after the other)")
    # this shared machine's speed drifts by 10-20 % within seconds: the two engines in turns, the median ratio
    (netlogo, netlogo_feeds), (phased, phased_feeds) = batches["netlogo"], batches["phased"]
    ratios = [best_rate(netlogo, netlogo_feeds, 1) / best_rate(phased, phased_feeds, 1) for _ in range(args.rounds)]
    result[f"netlogo_over_phased_batch{args.agents}_median"] = round(float(np.median(ratios)), 3)
    print(
        f"netlogo / phased at A = {args.agents}, {args.rounds} round{'s' * (args.rounds != 1)} in turns: "
        f"median {np.median(ratios):.2f} "
        f"(min {min(ratios):.2f}, max {max(ratios):.2f})"
    )
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
