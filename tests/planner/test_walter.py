"""Walter, Tsai & Amato (seed 003): the PC's half (section 4) and the round model (section 5)."""

from __future__ import annotations

import networkx as nx
import pytest

from bus.lattice import Cell, Direction
from planner_svc.planners.rules import find_move
from planner_svc.planners.walter import (Inadmissible, RoundModel, build_h, candidates, check_chain, choose,
                                         path_cost, path_violation, traverse_graph)
from planner_svc.planners.walter.frame import Heading, turn
from planner_svc.planners.walter.goals import generate
from planner_svc.planners.walter.rounds import DELAYS, flips

# Figure 8's DAG, as the goal it is H of: A in G_1 ... G in G_5 (our cells, orientation 0).
A, B, C, D, E, F, G = (Cell(0, 0), Cell(1, 0), Cell(2, 0), Cell(2, -1), Cell(3, -1), Cell(3, -2),
                       Cell(4, -2))
FIG8 = frozenset({A, B, C, D, E, F, G})


def chain_to(c0: Cell, heading: Heading, n: int) -> list[Cell]:
    cells = [c0]
    for _ in range(n - 1):
        cells.append(heading.of(cells[-1]))
    return cells[::-1]


# --- section 4: H and TraverseGraph ---------------------------------------------------------
def test_figure8_h_has_the_papers_edges():
    h = build_h(FIG8)
    assert set(h.graph.edges) == {(A, B), (B, C), (B, D), (C, E), (D, E), (D, F), (E, G), (F, G)}
    assert h.roots() == [A]


def test_figure8_traversal_order_and_costs():
    # Figure 8 (b), (d), (f): A-B-C-E-G first (the cost-1 path of 8(b)), then from B through
    # D and E, then from D through F.
    paths = [(p.cells, p.cost) for p in traverse_graph(build_h(FIG8), A)]
    assert paths == [((A, B, C, E, G), 1), ((A, B, D, E, G), 3), ((A, B, D, F, G), 2)]


@pytest.mark.parametrize("seed", range(4))
def test_traverse_graph_visits_every_root_to_leaf_path(seed):
    g = generate(14 + 3 * seed, ("0", "1", ">1", "1")[seed], seed=seed, world_safe=False).goal
    for k in range(6):
        turned = frozenset(turn(c, k) for c in g)
        try:
            h = build_h(turned)
        except (IndexError, ValueError):
            continue  # columns not contiguous in this orientation
        leaves = [v for v in h.graph if h.graph.out_degree(v) == 0]
        for root in h.roots():
            ours = sorted(p.cells for p in traverse_graph(h, root))
            theirs = sorted(tuple(p) for leaf in leaves
                            for p in nx.all_simple_paths(h.graph, root, leaf))
            assert ours == theirs
            for p in traverse_graph(h, root):
                assert p.cost == path_cost(p.cells)


def test_weights():
    assert path_cost([A, B, Cell(2, 0), Cell(3, 0)]) == 0                 # straight NE
    assert path_cost([A, B, C, E, G]) == 1                                # one bend
    assert path_cost([A, B, D, F, G]) == 2                                # NE SE SE NE
    assert path_cost([Cell(0, 0), Cell(1, -1), Cell(1, 0), Cell(2, 0)]) == 10 + 1  # a north edge


# --- section 4: admissibility, each condition refused with its reason -----------------------
def test_definition_2_1_no_westward_step():
    why = path_violation([Cell(0, 0), Cell(1, 0), Cell(0, 1)], frozenset())
    assert why.startswith("Definition 2.1") and "(1,0) -> (0,1) goes NW" in why


def test_definition_2_2a_north_segment_corner_is_not_goal():
    path = [Cell(0, 0), Cell(0, 1), Cell(1, 1)]
    why = path_violation(path, frozenset(path) | {Cell(1, 0)})
    assert why.startswith("Definition 2.2(a)") and "ending at (0,1)" in why and "(1,0)" in why


def test_definition_2_2b_north_then_south_within_three_cells():
    path = [Cell(0, 0), Cell(0, 1), Cell(1, 1), Cell(2, 1), Cell(2, 0)]
    why = path_violation(path, frozenset(path))
    assert why.startswith("Definition 2.2(b)") and "ending at (0,1)" in why


def test_definition_2_3_south_segment():
    path = [Cell(0, 0), Cell(0, -1), Cell(1, -2)]
    why = path_violation(path, frozenset(path) | {Cell(1, -1)})
    assert why.startswith("Definition 2.3(a)") and "(1,-1)" in why
    path = [Cell(0, 0), Cell(0, -1), Cell(1, -2), Cell(2, -3), Cell(2, -2)]
    assert path_violation(path, frozenset(path)).startswith("Definition 2.3(b)")


def test_admissible_path_passes():
    assert path_violation([A, B, C, E, G], FIG8) is None


def test_definition_3_i_must_meet_g_in_one_cell_at_its_end():
    goal = frozenset(chain_to(Cell(0, 0), Heading.NE, 4))
    with pytest.raises(Inadmissible, match="meets G in 2 cells"):
        check_chain(goal, [Cell(-2, 0), Cell(-1, 0), Cell(0, 0), Cell(1, 0)])
    with pytest.raises(Inadmissible, match="not a straight chain"):
        check_chain(goal, [Cell(-3, 0), Cell(-2, 0), Cell(-2, 1), Cell(0, 0)])
    # Definition 3: p begins where I meets G, in G_1: orientations where it is not say so
    _, why = candidates(goal, Cell(1, 0))
    assert "orientation 0: Definition 3: I meets G at (1,0), not in the westernmost column G_1" in why


def test_definition_4_an_orientation_without_admissible_substrate_path_says_where():
    # In orientation 0 the only way east is down column 1 to (1,-3), and that south
    # segment's corner cell Z = (3,-3) is a goal cell.
    goal = frozenset({Cell(0, 0), Cell(1, -1), Cell(1, -2), Cell(1, -3), Cell(2, -4), Cell(3, -4),
                      Cell(3, -3)})
    _, why = candidates(goal)
    assert why[0] == ("orientation 0: Definition 4: no admissible substrate path (no cell of "
                      "column G_1 reaches G_m; Definition 2.3(a): no south edge (1,-2) -> (1,-3): "
                      "(3,-3) is a goal cell (Figure 4: X, Y, Z))")
    assert choose(goal, model=False).orientation == 3  # from the east it is admissible


def test_columns_must_be_contiguous_in_some_orientation():
    ring = frozenset(Cell(0, 0).neighbours())  # a ring of six: a gap in some column everywhere
    with pytest.raises(Inadmissible) as exc:
        choose(ring)
    msg = str(exc.value)
    assert msg.startswith("inadmissible goal: orientation 0: column ") and "\n" not in msg
    assert "is not one contiguous north-south chain (gap at" in msg


# --- section 5: the round model ---------------------------------------------------------------
def replay(model: RoundModel) -> None:
    """Independent checks of a run: cells never doubly occupied, each move a rotation of one
    cell about an immobile neighbour adjacent to both cells, the goal reached."""
    occupied = {m: c for m, c in enumerate(model.chain)}
    for r in model.rounds:
        cells = set(occupied.values())
        moving = {mv.module for mv in r.moves}
        targets = [mv.to_cell for mv in r.moves]
        assert len(targets) == len(set(targets)), f"round {r.number}: two movers, one cell"
        for mv in r.moves:
            assert occupied[mv.module] == mv.from_cell
            assert mv.to_cell not in cells
            assert mv.from_cell.side_towards(mv.to_cell) is not None
            assert mv.substrate in cells and mv.substrate not in {occupied[m] for m in moving}
            assert mv.substrate.side_towards(mv.from_cell) and mv.substrate.side_towards(mv.to_cell)
        for mv in r.moves:
            occupied[mv.module] = mv.to_cell
        assert len(set(occupied.values())) == len(occupied)
    assert set(occupied.values()) == set(model.goal)


def round_bound(model: RoundModel) -> int:
    """Our bound (the paper's text gives none in closed form): every module is free at most
    two rounds after the one before it leaves, waits its delay, and walks at most along I
    (n - 1 cells) and once around G (at most 2n + 4 cells)."""
    n = model.n
    return sum(2 + e.delay for e in model.schedule.entries) + (n - 1) + (2 * n + 4)


def test_straight_goal_paper_rules():
    goal = chain_to(Cell(0, 0), Heading.NE, 6)[::-1]
    model = RoundModel(goal, chain_to(Cell(0, 0), Heading.SW, 6), goal, rules="paper")
    rep = model.report()
    assert rep.reached and not rep.collisions and not rep.stuck
    replay(model)
    # (0,0)-bidirectional: module 0 leaves CW in round 1, module 1 CCW two rounds later
    assert model.rounds[0].moves[0][:2] == (0, Direction.CW)
    assert model.rounds[2].moves[1][:2] == (1, Direction.CCW)
    assert rep.rounds <= round_bound(model)


def test_straight_goal_hexbot_rules_are_legal_in_the_world():
    goal = chain_to(Cell(0, 0), Heading.NE, 6)[::-1]
    model = RoundModel(goal, chain_to(Cell(0, 0), Heading.SW, 6), goal)
    rep = model.report()
    assert rep.reached and not rep.collisions and not rep.world_refusals
    paper = RoundModel(goal, chain_to(Cell(0, 0), Heading.SW, 6), goal, rules="paper").report()
    # the paper's spacing (one empty cell between movers on a side) is too close for a HexBot
    assert paper.world_refusals and paper.rounds < rep.rounds


def test_isfree_flips():
    assert flips([True, False, False, False, False, False]) == 2
    assert flips([True, True, True, True, False, False]) == 2
    assert flips([True, False, True, False, False, False]) == 4


def holds_the_papers_claims(gen) -> None:
    """With the paper's delays and ours: the goal reached, no collision, every move replayed,
    within the bound."""
    c = gen.choice
    for rules in DELAYS:
        model = RoundModel(gen.goal, c.chain, c.path, c.orientation, rules=rules)
        rep = model.report()
        assert rep.reached and not rep.collisions, (rules, rep.collisions[:3], rep.stuck)
        replay(model)
        assert rep.rounds <= round_bound(model)


@pytest.mark.parametrize("cost_class", ["0", "1", ">1"])
@pytest.mark.parametrize("n", [6, 11, 20])
def test_generated_goals_reach_the_goal_without_collision(n, cost_class):
    gen = generate(n, cost_class, seed=1)
    c = gen.choice
    assert c.candidate.cost_class == cost_class and len(gen.goal) == n
    holds_the_papers_claims(gen)
    model = RoundModel(gen.goal, c.chain, c.path, c.orientation)
    model.run()
    assert not model.world_refusals
    # the world's rule, move by move, all moves of a round at once
    occ = set(model.chain)
    for r in model.rounds:
        for mv in r.moves:
            others = [find_move(occ, o.from_cell, o.to_cell, model.chain[-1]) for o in r.moves
                      if o is not mv]
            assert find_move(occ, mv.from_cell, mv.to_cell, model.chain[-1],
                             concurrent=[o for o in others if o]) is not None
        occ = (occ - {mv.from_cell for mv in r.moves}) | {mv.to_cell for mv in r.moves}


@pytest.mark.parametrize("cost_class", ["0", "1", ">1"])
def test_sixty_modules_every_cost_class(cost_class):
    # The paper's claims at the top of the range: reached, no collision, within the bound, with
    # its own delays and ours (HexBot-world legality at this size is not asked: see docs).
    gen = generate(60, cost_class, seed=1, world_safe=False)
    c = gen.choice
    assert len(gen.goal) == 60 and c.candidate.cost_class == cost_class
    holds_the_papers_claims(gen)


def test_positions_are_learned_by_counting_passers():
    gen = generate(12, "1", seed=2)
    c = gen.choice
    model = RoundModel(gen.goal, c.chain, c.path, c.orientation)
    model.run()
    final = model.rounds[-1].states
    assert all(final[i].position == i for i in range(model.n - 1))
    assert not any("counted" in x for x in model.collisions)


# --- the scenarios of the paper's figures, the planner and the CLI -------------------------------
def test_scenario_planner_key_and_typo():
    from bus.scenario import PLANNERS, ScenarioError, load, loads
    from planner_svc import planners
    assert set(PLANNERS) == set(planners.names())
    assert load("walter-fig8").planner == "walter"
    with pytest.raises(ScenarioError, match=r"line 1, key 'planner': expected a planner: .*"
                                            r"\(did you mean 'walter'\?\), got 'waltr'"):
        loads('planner = "waltr"\ninitial = [[0, 0], [1, 0]]\n')


def test_figure8_scenario_follows_the_papers_selection_rule():
    # The cost-1 path A-B-C-E-G leaves 0 cells north and 2 south: not within one module of
    # bisecting G, so the paper goes on to the most even path, A-B-D-E-G (1 / 1), cost 3.
    from bus.scenario import load
    sc = load("walter-fig8")
    c = choose(sc.goal, [m.cell for m in sc.modules], rules="paper")
    assert c.path == (A, B, D, E, G) and c.cost == 3 and (c.candidate.north, c.candidate.south) == (1, 1)
    assert c.reached and not c.collisions


@pytest.mark.parametrize("name", ["walter-fig3", "walter-fig5a", "walter-fig8", "walter-fig9"])
def test_figure_scenarios_plan_legal_moves_to_the_goal(name):
    from bus.scenario import load
    from planner_svc import planners
    from planner_svc.planners.plan import validate
    plan = planners.get("walter").plan(load(name))
    assert plan.ok, plan.reason
    validate(plan)  # every round's moves, all at once, through the one move rule
    assert any(n.startswith("rounds predicted: ") for n in plan.notes)


def test_figure5b_is_refused_before_anything_moves():
    from bus.scenario import load
    from planner_svc import planners
    plan = planners.get("walter").plan(load("walter-fig5b"))
    assert not plan.ok and not plan.steps
    assert plan.reason.startswith("inadmissible goal: orientation 0: column 2 is not one "
                                  "contiguous north-south chain (gap at (1,-1))")


def test_figure9_contact_patterns():
    # Figure 9: a module that is not moving is trapped (the hardware holds it: contacts not
    # one run, or five or more), free (Figure 10 lets it go) or other (it could move, but the
    # algorithm holds it: stopped in its goal cell, or the module beyond it in I still there).
    from bus.scenario import load
    from planner_svc.planners.walter.rounds import contact_pattern
    sc = load("walter-fig9")
    c = choose(sc.goal, [m.cell for m in sc.modules])
    model = c.model()
    seen = set()
    for r in model.run():
        occ = {st.cell for st in r.states.values()}
        for i, st in r.states.items():
            if i < model.n - 1 and (st.done or not st.free):
                contacts = [st.cell.neighbour(s) in occ for s in range(1, 7)]
                held = st.done or (i > 0 and model.chain[i - 1] in occ)
                seen.add(contact_pattern(contacts, held))
    assert seen == {"trapped", "free", "other"}


def test_hexbench_plan_walter_prints_path_cost_rounds_and_draws(tmp_path, capsys):
    from hexbench.cli import main
    png = tmp_path / "fig8.png"
    assert main(["plan", "walter-fig8", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "note: substrate path: (0,0) (1,0) (2,-1) (3,-1) (4,-2)" in out
    assert "note: substrate path cost: 3" in out and "note: rounds predicted: 28" in out
    assert png.stat().st_size > 10_000
    assert main(["plan", "walter-fig5b", "--planner", "walter"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("walter on walter-fig5b: FAILED: inadmissible goal: orientation 0")
