"""Train a population of insects in one process with spikinglab's Python API (docs/api.md).

Eight insects, each in its own arena, learn at A+ = A- = 0.04; every 5,000 ticks (and at the end,
where the ticks asked for are not a multiple of 5,000) the script prints the collisions since the
row before and the mean weight from the black-smell neuron to the pain neuron, then each insect's
learning time (its last collision before 5,000 collision-free ticks).
Run: `python examples/train_population.py [ticks]` (default 60,000).
"""

import numpy as np

from services.options import Parser, at_least
from spikinglab import World, brain_for, closed_loop, load_circuit, params_for

ROW = 5_000  # ticks between printed rows

p = Parser(description=(__doc__ or "").splitlines()[0])
p.add_argument("ticks", type=at_least(1), nargs="?", default=60_000, help="ticks to train (default 60,000)")
ticks = p.parse_args().ticks
world = World(params_for("paper"), agents=8, seed=1)
circuit = load_circuit("insect").with_learning_rate(0.04)
brain = brain_for(world, circuit)
black_pain = [circuit.synapse_label(k) for k in range(len(circuit.synapses))].index("BLACK->PAIN")

print("ticks    collisions (8 insects)   mean weight BLACK->PAIN")
before = world.metrics.collisions.copy()
for start in range(0, ticks, ROW):
    done = min(start + ROW, ticks)  # the last block is shorter where ticks is not a multiple of ROW
    closed_loop(world, brain, done - start)
    now = world.metrics.collisions.copy()
    weight = brain.engine.get_weights()[:, black_pain].mean()
    print(f"{done:6,}   {int((now - before).sum()):10d}               {weight:6.2f}")
    before = now
learned = world.metrics.learned_at
print("learned at:", ", ".join(f"{t:,}" if t >= 0 else "not yet" for t in learned))
print(f"{np.sum(learned >= 0)} of {world.agents} insects learned within {ticks:,} ticks")
