"""Draw a plan as hexagons, one panel per time step (thesis Fig. 5-8 style), to PNG."""

from __future__ import annotations

import math
from pathlib import Path

from bus.lattice import Cell

from .plan import Plan

FILL = "#9ecae1"        # occupied cell
MOVER = "#31a354"       # module that moves in this step (before its move)
ARRIVAL = "#a1d99b"     # where it arrives
FIXED = "#3182bd"       # the module fixed to the base
GOAL_EDGE = "#e6550d"   # goal cells are outlined


def draw_plan(plan: Plan, path: str | Path, columns: int = 4, max_panels: int = 48) -> Path:
    """Write a PNG of ``plan``: the initial configuration, then each step.

    Occupied cells are filled, goal cells outlined, the moving module highlighted with
    an arrow to its next cell. Long plans are cut to ``max_panels`` panels (the last
    panel is always the final configuration).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    confs = plan.configurations()
    steps = plan.steps + [[]]
    idx = list(range(len(confs)))
    if len(idx) > max_panels:
        idx = idx[:max_panels - 1] + [idx[-1]]
    goal = plan.problem.goal
    every = set().union(*confs, goal, plan.problem.obstacles)
    xs = [v[0] for c in every for v in c.vertices()]
    ys = [v[1] for c in every for v in c.vertices()]
    rows = math.ceil(len(idx) / columns)
    cols = min(columns, len(idx))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.0 * rows), squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    for ax, k in zip(axes.flat, idx):
        occ = confs[k]
        moving = {m.mobile: m.goal for m in steps[k]}
        for cell in sorted(every | set(moving.values())):
            face = "none"
            if cell in occ:
                face = FIXED if cell == plan.problem.fixed else FILL
            if cell in moving:
                face = MOVER
            elif cell in moving.values():
                face = ARRIVAL
            if cell in plan.problem.obstacles:
                face = "#636363"
            edge = GOAL_EDGE if cell in goal else "#bdbdbd"
            ax.add_patch(Polygon(cell.vertices(), closed=True, facecolor=face, edgecolor=edge,
                                 linewidth=2.0 if cell in goal else 0.6))
        arrows(ax, moving, lw=1.2)
        title = "initial" if k == 0 else f"after step {k}"
        if k < len(plan.steps):
            title += f" | step {k + 1}: {len(plan.steps[k])} move(s)"
        ax.set_title(title, fontsize=8)
        fit(ax, xs, ys)
    status = "goal reached" if plan.ok else f"stopped: {plan.reason}"
    fig.suptitle(f"{plan.planner} on {plan.problem.name}: {len(plan.steps)} steps, "
                 f"{plan.moves} moves ({status})", fontsize=10)
    return save(fig, path)


def arrows(ax, moving: dict[Cell, Cell], lw: float) -> None:
    """An arrow from each mover's cell to the cell it arrives in."""
    for a, b in moving.items():
        (x0, y0), (x1, y1) = a.centre(), b.centre()
        ax.annotate("", xy=(x1, y1), xytext=(x0, y0),
                    arrowprops=dict(arrowstyle="->", color="black", lw=lw))


def fit(ax, xs: list[float], ys: list[float]) -> None:
    """Every panel the same window around the cells drawn, hexagons not stretched."""
    ax.set_xlim(min(xs) - 0.2, max(xs) + 0.2)
    ax.set_ylim(min(ys) - 0.2, max(ys) + 0.2)
    ax.set_aspect("equal")


def save(fig, path: str | Path) -> Path:
    """Lay the panels out, write the PNG and free the figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


__all__ = ["draw_plan", "Cell"]
