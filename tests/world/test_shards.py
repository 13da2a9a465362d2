"""Shards of a fleet (module_sim.shards): equal parts, neighbours kept together, the same
parts every time."""

from collections import Counter

import pytest

from bus.lattice import Cell
from bus.scenario import load
from module_sim.shards import cut_pairs, neighbour_graph, partition


def test_two_shards_of_thesis_12_are_halves_cut_across_few_pairs():
    cells = [m.cell for m in load("thesis-12").modules]
    part = partition(cells, 2)
    assert sorted(Counter(part).values()) == [6, 6]
    assert cut_pairs(cells, part) <= len(neighbour_graph(cells).edges) // 4
    assert part == partition(cells, 2)  # seeded: the same parts every time


@pytest.mark.parametrize("parts", [2, 3, 4])
def test_a_block_of_1000_splits_into_equal_connected_parts(parts):
    cells = [Cell(x, y) for x in range(40) for y in range(25)]
    part = partition(cells, parts)
    sizes = Counter(part)
    assert max(sizes.values()) - min(sizes.values()) <= 1
    g = neighbour_graph(cells)
    import networkx as nx
    for k in range(parts):  # each shard is one piece of the lattice, not scattered cells
        assert nx.is_connected(g.subgraph([i for i, p in enumerate(part) if p == k]))
    # at most a few cells' width of border per cut: 25 rows across, ~3 pairs a row
    assert cut_pairs(cells, part) <= 90 * (parts - 1)


def test_impossible_partitions_are_refused_with_the_reason():
    cells = [Cell(0, 0), Cell(0, 1)]
    with pytest.raises(ValueError, match="3 parts for 2 modules"):
        partition(cells, 3)
    with pytest.raises(ValueError, match="at least 1"):
        partition(cells, 0)
