"""The thesis layers against the worked examples of Ch. 4 (Fig. 4-16..4-28).

The Ch. 4 example is ``thesis-6``. Fig. 4-24 labels cells by column-major linear
index in the 5-row, 8-column matrix of ``Test_VP`` (the example shifted by x+2, y+1),
so PV(12), PV(23), ME(14), ME(34) are (0,2), (2,1), (0,0), (4,0) here.
"""

from bus.lattice import Cell
from bus.scenario import load

from planner_svc.planners import thesis

I = set(load("thesis-6").initial)
G = set(load("thesis-6").goal)


def cells(*xy):
    return frozenset(Cell(x, y) for x, y in xy)


def test_electrons_and_voids_fig_4_16():
    e, v = thesis.electrons_and_voids(I, G)
    assert e == cells((0, 0), (3, 0), (4, 0))
    assert v == cells((0, 2), (1, 2), (2, 1))


def test_mobile_electrons_fig_4_17():
    e, _ = thesis.electrons_and_voids(I, G)
    # (3,0) holds (4,0) on: an articulation point, immobile (the yellow electron).
    assert thesis.mobile_electrons(e, I) == cells((0, 0), (4, 0))


def test_potential_voids_fig_4_17():
    e, v = thesis.electrons_and_voids(I, G)
    me = thesis.mobile_electrons(e, I)
    # (1,2) touches no immobile module: not yet fillable.
    assert thesis.potential_voids(v, I, me) == cells((0, 2), (2, 1))


def test_reversed_example_fig_4_18_three_mobile_electrons_two_potential_voids():
    e, v = thesis.electrons_and_voids(G, I)
    me = thesis.mobile_electrons(e, G)
    assert len(me) == 3 and len(thesis.potential_voids(v, G, me)) == 2


def test_mobile_needs_fewer_than_four_neighbours():
    blob = cells((0, 0), (1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1))
    # The centre is no articulation point but has six neighbours: it cannot move.
    assert Cell(0, 0) not in thesis.mobile_electrons({Cell(0, 0)}, blob)


def test_connectivity_example_fig_4_21_articulation_nodes():
    rows = ["0 0 0 0 0 0 0 0", "0 1 1 1 1 0 0 0", "0 1 0 1 0 0 1 0",
            "0 1 0 1 0 1 1 0", "0 0 1 1 1 1 1 0", "0 0 0 0 0 0 0 0"]
    from bus.lattice import matrix_to_cells
    conf = set(matrix_to_cells(rows))
    me = thesis.mobile_electrons(conf, conf)
    # Column-major linear indices of a 6-row matrix: 20, 29, 35, 40 are immobile.
    def index(c):
        return (6 - c.y) + c.x * 6
    assert sorted(index(c) for c in conf - me) == [20, 29, 35, 40]


def test_void_wave_fig_4_24():
    e, _ = thesis.electrons_and_voids(I, G)
    me = thesis.mobile_electrons(e, I)
    assert thesis.void_wave(I, me, Cell(0, 2))[0] == (Cell(0, 0), 3)   # (12,3) reaches ME(14)
    assert thesis.void_wave(I, me, Cell(2, 1))[0] == (Cell(4, 0), 2)   # PV(23) finds ME(34)


def test_void_propagation_pairs_shortest_first():
    pairs = thesis.void_propagation(I, G)
    assert [(p.void, p.electron, p.time) for p in pairs] == [
        (Cell(2, 1), Cell(4, 0), 2), (Cell(0, 2), Cell(0, 0), 3)]


def test_mdp_states_and_rewards_fig_4_27():
    e, _ = thesis.electrons_and_voids(I, G)
    me = thesis.mobile_electrons(e, I)
    states = thesis.mdp_states(I, me)
    # The magenta cells of Fig. 4-27 c), read off the reward matrix R of Fig. 4-27 d).
    assert states == cells((-1, 2), (0, 2), (-1, 1), (1, 1), (2, 1), (3, 1), (0, 0), (4, 0),
                           (1, -1), (2, -1), (3, -1), (4, -1))
    r = thesis.mdp_rewards(states, me, Cell(0, 0), Cell(0, 2))
    assert r[Cell(0, 2)] == 1 and r[Cell(4, 0)] == -1
    assert all(v == -0.04 for c, v in r.items() if c not in (Cell(0, 2), Cell(4, 0)))


def test_value_function_fig_4_28_ordering_and_next_location():
    nxt, vf = thesis.next_location(I, G, Cell(0, 0), Cell(0, 2))
    u = vf.values
    assert u[Cell(0, 2)] == 1.0 == max(u.values())          # normalised at the void
    assert u[Cell(4, 0)] == min(u.values())                  # the other electron is avoided
    # Closer to s2 is better: along the path the electron will take.
    assert u[Cell(-1, 2)] > u[Cell(-1, 1)] > u[Cell(0, 0)]
    assert u[Cell(3, 1)] > u[Cell(4, -1)] > u[Cell(4, 0)]
    assert nxt == Cell(-1, 1)
    assert vf.iterations < 500 and vf.max_change < thesis.TOLERANCE


def test_test_mdp_walk_reaches_the_void():
    """Test_MDP: following the next recommended location reaches the void."""
    occ, s = set(I), Cell(0, 0)
    path = []
    while s != Cell(0, 2):
        nxt, _ = thesis.next_location(occ, G, s, Cell(0, 2))
        assert nxt != s
        occ = occ - {s} | {nxt}
        s = nxt
        path.append(s)
    assert path == [Cell(-1, 1), Cell(-1, 2), Cell(0, 2)]


def test_value_iteration_discount_horizon():
    """Table 4-2's point: a smaller discount needs fewer iterations."""
    r = {Cell(i, 0): -0.04 for i in range(10)}
    r[Cell(9, 0)] = 1.0
    fast = thesis.value_iteration(r, gamma=0.3)
    slow = thesis.value_iteration(r, gamma=0.9)
    assert fast.iterations < slow.iterations


def test_actuation_table_4_3():
    mv = thesis.actuation(I, Cell(0, 0), Cell(-1, 1), fixed=Cell(1, 0))
    assert mv is not None
    assert (int(mv.joint), mv.direction.value, mv.substrate) == (2, "CW", Cell(0, 1))
    # The mobile's other neighbour (1,0) must open the joints of its facing side 4.
    assert {c for c, _ in mv.release} == {Cell(1, 0)}
    assert {int(j) for _, j in mv.release} == {6, 1}
    # No substrate for (4,0) -> (5,0): no rotation.
    assert thesis.actuation(I, Cell(4, 0), Cell(5, 0), fixed=Cell(1, 0)) is None
