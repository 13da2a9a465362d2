"""``--planner walter`` behind the planners' one interface: a :class:`Plan` whose steps are
the round model's moves (rounds without a move left out), refused goals as its reason."""

from __future__ import annotations

from ..plan import Plan
from .choose import Choice, Inadmissible, choose


def plan_walter(plan: Plan) -> Choice | None:
    """Fill ``plan``; returns the choice (None for a refused goal)."""
    p = plan.problem
    try:
        choice = choose(p.goal, sorted(p.initial, key=lambda c: (c.x, c.y)))
    except Inadmissible as exc:
        plan.reason = str(exc)
        return None
    model = choice.model()
    rep = model.report()
    c = choice.candidate
    plan.notes += [
        f"substrate path: {' '.join(map(str, c.path))} (orientation {c.orientation})",
        f"substrate path cost: {c.cost} (class {c.cost_class}); splits G {c.north} north / "
        f"{c.south} south; {choice.candidates} admissible substrate paths",
        f"rounds predicted: {rep.rounds} ({rep.moves} moves; first sense "
        f"{model.schedule.first.value})",
    ]
    steps = model.world_moves()
    if rep.collisions or rep.world_refusals or not rep.reached:
        first = (rep.collisions or rep.world_refusals or [rep.stuck])[0]
        bad_round = int(first.split()[1].rstrip(":")) if first.startswith("round ") else 0
        kept = sum(1 for r in model.rounds[:max(0, bad_round - 1)] if r.moves)
        plan.steps = steps[:kept]
        plan.reason = (f"the round model breaks a rule: {first}" if rep.collisions else
                       f"the HexBot world would refuse {len(rep.world_refusals)} of the round "
                       f"model's moves (Table 4-3), first {first}" if rep.world_refusals else
                       f"the round model did not reach the goal: {rep.stuck}")
        return choice
    plan.steps = steps
    plan.ok = True
    return choice
