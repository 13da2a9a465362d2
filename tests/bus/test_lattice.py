"""The lattice against Table 4-1, Table 4-3 and the thesis matrices (spec §2, §8, §11)."""

import math

import pytest
from hypothesis import given, strategies as st

from bus import lattice
from bus.lattice import Cell, Direction, Joint, MOVE_RULES, Side

TABLE_4_1 = {1: ((-1, 1), 4), 2: ((0, 1), 5), 3: ((1, 0), 6), 4: ((1, -1), 1), 5: ((0, -1), 2),
             6: ((-1, 0), 3)}


@pytest.mark.parametrize("side", range(1, 7))
def test_table_4_1(side):
    (dx, dy), facing = TABLE_4_1[side]
    c = Cell(3, -2)
    n = c.neighbour(side)
    assert (n.x - c.x, n.y - c.y) == (dx, dy)
    assert Side(side).facing == facing
    assert n.neighbour(facing) == c
    assert c.side_towards(n) == side


@pytest.mark.parametrize("side", range(1, 7))
def test_neighbour_centres_are_one_apart_across_the_side(side):
    c = Cell(0, 0)
    n = c.neighbour(side)
    (x0, y0), (x1, y1) = c.centre(), n.centre()
    assert math.dist((x0, y0), (x1, y1)) == pytest.approx(2 / math.sqrt(3))
    # the shared edge is side k of c: its joints k and k+1 are vertices of n too
    shared = [c.vertex(j) for j in Side(side).joints]
    for v in shared:
        assert min(math.dist(v, w) for w in n.vertices()) < 1e-9


def test_joint_side_relation():
    assert Side(1).joints == (Joint(1), Joint(2))
    assert Joint(1).sides == (Side(6), Side(1))
    assert Side(2).joints[0] == Joint(2)


def test_cartesian_matches_matlab_hex():
    px, py = Cell(2, 1).centre()
    assert px == 2 and py == pytest.approx(1 / math.sin(math.radians(60)) + 2 * math.tan(math.radians(30)))
    assert Cell(0, 0).vertex(1) == pytest.approx((-2 / 3, 0))
    assert Cell(0, 0).vertex(4) == pytest.approx((2 / 3, 0))


TABLE_4_3 = [  # joint, dir, substrate, empty, goal  (spec §8)
    (1, "CW", "A", "DEK", "F"), (2, "CW", "B", "EFL", "A"), (3, "CW", "C", "FAG", "B"),
    (4, "CW", "D", "ABH", "C"), (5, "CW", "E", "BCI", "D"), (6, "CW", "F", "CDJ", "E"),
    (1, "CCW", "F", "CBG", "A"), (2, "CCW", "A", "DCH", "B"), (3, "CCW", "B", "EDI", "C"),
    (4, "CCW", "C", "FEJ", "D"), (5, "CCW", "D", "AFK", "E"), (6, "CCW", "E", "BAL", "F"),
]


@pytest.mark.parametrize("row", TABLE_4_3)
def test_table_4_3(row):
    j, d, sub, empty, goal = row
    r = lattice.move_rule(j, d)
    assert (r.substrate, "".join(r.empty), r.goal) == (sub, empty, goal)


@pytest.mark.parametrize("rule", MOVE_RULES, ids=lambda r: f"J{int(r.joint)}{r.direction.value}")
def test_table_4_3_agrees_with_geometry(rule):
    """Rotating the mobile 120 degrees about the pivot joint lands on the goal cell, and the
    substrate shares that pivot vertex."""
    m = Cell(1, 1)
    sub, empty, goal = rule.cells(m)
    pivot = m.vertex(rule.joint)
    angle = -120 if rule.direction is Direction.CW else 120
    assert lattice.rotate_about_vertex(m.centre(), pivot, angle) == pytest.approx(goal.centre())
    assert min(math.dist(pivot, v) for v in sub.vertices()) < 1e-9
    assert m.distance(goal) == 1 and m.distance(sub) == 1 and goal not in empty


def test_letters_are_the_sides_and_second_ring():
    m = Cell(0, 0)
    for k, letter in enumerate("ABCDEF", start=1):
        assert lattice.matrix_offset_to_cell(m, *lattice.LETTER_OFFSET[letter]) == m.neighbour(k)
    for letter in "GHIJKL":
        assert m.distance(lattice.matrix_offset_to_cell(m, *lattice.LETTER_OFFSET[letter])) == 2


def test_matrix_to_cells_thesis_6():
    initial = ["0 0 0 0 0", "1 0 0 0 0", "1 1 1 1 1"]
    goal = ["1 1 0 0 0", "1 0 1 0 0", "0 1 1 0 0"]
    assert set(lattice.matrix_to_cells(initial)) == {Cell(0, 1)} | {Cell(x, 0) for x in range(5)}
    assert set(lattice.matrix_to_cells(goal)) == {Cell(0, 2), Cell(1, 2), Cell(0, 1), Cell(2, 1),
                                                 Cell(1, 0), Cell(2, 0)}
    assert lattice.cells_to_matrix(lattice.matrix_to_cells(goal), 3, 5) == \
        [[int(v) for v in r.split()] for r in goal]


def test_matrix_neighbours_agree_with_hexnem():
    # HexNeM (matrix indices): side1 (i-1, j-1), side2 (i-1, j), side3 (i, j+1),
    # side4 (i+1, j+1), side5 (i+1, j), side6 (i, j-1)
    hexnem = {1: (-1, -1), 2: (-1, 0), 3: (0, 1), 4: (1, 1), 5: (1, 0), 6: (0, -1)}
    c = Cell(4, 4)
    for s, (di, dj) in hexnem.items():
        assert lattice.matrix_offset_to_cell(c, di, dj) == c.neighbour(s)


@given(st.lists(st.tuples(st.integers(0, 8), st.integers(0, 8)), unique=True, max_size=30))
def test_matrix_round_trip(cells):
    cs = [Cell(x, y) for x, y in cells]
    m = lattice.cells_to_matrix(cs, 9, 9)
    assert set(lattice.matrix_to_cells(m)) == set(cs)


@given(side=st.integers(1, 6), yref=st.integers(0, 5))
def test_body_global_round_trip(side, yref):
    g = lattice.body_to_global(side, yref)
    assert lattice.global_to_body(g, yref) == side
    assert lattice.joint_global_to_body(lattice.joint_body_to_global(side, yref), yref) == side


def test_yref_definition_matches_localization():
    # spec §9: a receiver that hears global side S on body side j sets Yref = S - j (mod 6)
    for s in range(1, 7):
        for j in range(1, 7):
            yref = (s - j) % 6
            assert lattice.body_to_global(j, yref) == s


@given(a=st.tuples(st.integers(-20, 20), st.integers(-20, 20)),
       b=st.tuples(st.integers(-20, 20), st.integers(-20, 20)))
def test_hex_distance_is_a_metric_consistent_with_neighbours(a, b):
    ca, cb = Cell(*a), Cell(*b)
    d = ca.distance(cb)
    assert d == cb.distance(ca) and (d == 0) == (ca == cb)
    if d:
        assert min(n.distance(cb) for n in ca.neighbours()) == d - 1
