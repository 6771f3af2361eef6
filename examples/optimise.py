"""Search two learning parameters with CMA-ES (the `cma` library), every generation one population.

Each generation's candidates (A+ = A-, and w_max), each on every seed, train together as one
population through `spikinglab.evaluate`; the cost of a candidate is its mean learning time over
the seeds, an insect that did not learn counting as the run's length plus its collisions in the
run's last quarter (so that among insects still colliding, fewer collisions rank better).
Run: `pip install cma` (or `pip install -e '.[optimise]'`), then
`python examples/optimise.py [--generations 10] [--ticks 60000] [--seeds 4] [--population 8]`.
With `--cluster tcp://HOST:PORT` (`pip install -e '.[optimise,cluster]'`, docs/cluster.md) each
generation runs in blocks on a Dask cluster, with the same costs, so the same search; a worker lost
mid-generation has its blocks run again on the others.
"""

import argparse
import sys

import numpy as np
from tqdm import tqdm

from services.cluster import ClusterError, address_option, check_cluster
from services.options import at_least
from services.world.world import BIN
from spikinglab import evaluate

try:
    import cma
except ImportError:
    sys.exit("optimise.py: the optimiser is the cma library: pip install -e '.[optimise]'")

# the search space: A+ = A- from 0.005 to 0.08 (the paper's Table 1 spans 0.01 .. 0.04 and its robot
# ran at 0.08), w_max from the circuit's initial plastic weight 5 to 30 (the model's: 15)
LOW, HIGH = np.array([0.005, 5.0]), np.array([0.08, 30.0])


def to_params(x):
    """CMA-ES searches [0, 1]^2; this maps a point to (A+, w_max)."""
    return LOW + np.clip(x, 0, 1) * (HIGH - LOW)


def cost(result, ticks):
    learned = result["learning_time"]
    per_insect = np.where(learned >= 0, learned, ticks + result["collisions_last_quarter"])
    return per_insect.mean(axis=1)


def main():
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--generations", type=at_least(1), default=10, help="generations of the search (default 10)")
    # the cost reads the collisions of the run's last quarter: at least one bin of them
    p.add_argument("--ticks", type=at_least(BIN), default=60_000, help="ticks each candidate runs (default 60,000)")
    p.add_argument("--seeds", type=at_least(1), default=4, help="seeds each candidate runs on (default 4)")
    p.add_argument(
        "--population", type=at_least(2), default=8, help="candidates per generation (CMA-ES: 2 or more; default 8)"
    )
    p.add_argument("--cluster", type=address_option, metavar="ADDRESS", help="a Dask scheduler, tcp://HOST:PORT")
    args = p.parse_args()
    try:
        if args.cluster is not None:
            check_cluster(args.cluster)  # before the first generation's progress bar
        search(args)
    except ClusterError as e:
        p.exit(1, f"{p.prog}: {e}\n")
    except KeyboardInterrupt:
        p.exit(130, f"{p.prog}: interrupted (the generations above are the search so far)\n")


def generation_costs(points, args):
    """Every candidate on every seed, one population (on the cluster: blocks, progress on stderr)."""
    a_plus, w_max = to_params(np.array(points)).T
    params = {"a_plus": a_plus, "a_minus": a_plus, "w_max": w_max}
    with tqdm(total=len(points) * args.seeds, unit="insect", leave=False, disable=args.cluster is None) as bar:
        return a_plus, w_max, evaluate(params, args.ticks, range(args.seeds), cluster=args.cluster, on_block=bar.update)


def search(args):
    start = (np.array([0.02, 15.0]) - LOW) / (HIGH - LOW)  # the model's values
    es = cma.CMAEvolutionStrategy(start, 0.3, {"bounds": [0, 1], "popsize": args.population, "seed": 1, "verbose": -9})
    best = (np.inf, (0.0, 0.0, []))  # cost, then A+ = A-, w_max and the learning times of the best
    for generation in range(1, args.generations + 1):
        points = es.ask()
        a_plus, w_max, result = generation_costs(points, args)
        costs = cost(result, args.ticks)
        es.tell(points, costs.tolist())
        k = int(np.argmin(costs))
        if costs[k] < best[0]:
            best = (costs[k], (a_plus[k], w_max[k], result["learning_time"][k]))
        print(
            f"generation {generation}: {len(points)} candidates x {args.seeds} seeds, best cost {costs[k]:,.0f} "
            f"at A+ = A- = {a_plus[k]:.4f}, w_max = {w_max[k]:.2f}",
            flush=True,
        )
    value, (a, w, times) = best
    print(
        f"best: A+ = A- = {a:.4f}, w_max = {w:.2f}, cost {value:,.0f}, learning times "
        f"{', '.join(f'{t:,}' if t >= 0 else 'not yet' for t in times)}"
    )


if __name__ == "__main__":
    main()
