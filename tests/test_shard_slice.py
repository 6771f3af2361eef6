"""How a population is cut into the shards of a sharded brain (brain --shard I/N, world --shards N)."""

import pytest

from services.options import shard_slice


@pytest.mark.parametrize("agents,shards", [(1, 1), (7, 3), (8, 8), (1000, 7), (5, 2)])
def test_the_shards_take_the_population_in_order_each_agent_once(agents, shards):
    slices = [shard_slice(agents, (i, shards)) for i in range(1, shards + 1)]
    assert slices[0][0] == 0 and slices[-1][1] == agents
    assert all(hi == lo for (_, hi), (lo, _) in zip(slices, slices[1:]))  # each starts where the last ended
    sizes = [hi - lo for lo, hi in slices]
    assert max(sizes) - min(sizes) <= 1 and min(sizes) >= 1
