"""Draw a Walter plan to PNG: G, I and the substrate path (with its cost and the rounds
predicted), then the fleet at a few rounds, movers arrowed (the style of ``draw.py``)."""

from __future__ import annotations

import math
from pathlib import Path

from ..draw import ARRIVAL, FILL, FIXED, GOAL_EDGE, MOVER, arrows, fit, save
from .choose import Choice

PATH_EDGE = "#756bb1"   # substrate path cells


def draw_walter(choice: Choice, path: str | Path, panels: int = 12, columns: int = 4) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    model = choice.model()
    model.run()
    occ = [list(model.chain)]
    for r in model.rounds:
        cells = dict(enumerate(occ[-1]))
        for mv in r.moves:
            cells[mv.module] = mv.to_cell
        occ.append([cells[i] for i in range(model.n)])
    picks = sorted({0, *(round(k * len(model.rounds) / (panels - 2)) for k in range(1, panels - 1)),
                    len(model.rounds)})
    every = set(choice.goal) | {c for o in occ for c in o}
    xs = [v[0] for c in every for v in c.vertices()]
    ys = [v[1] for c in every for v in c.vertices()]
    n_panels = len(picks) + 1
    rows = math.ceil(n_panels / columns)
    cols = min(columns, n_panels)
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 3.0 * rows), squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    on_path = set(choice.path)

    def hexes(ax, cells, movers):
        for cell in sorted(every):
            face = "none"
            if cell in cells:
                face = FIXED if cell == model.chain[-1] else FILL
            if cell in movers:
                face = MOVER
            elif cell in movers.values():
                face = ARRIVAL
            edge = PATH_EDGE if cell in on_path else GOAL_EDGE if cell in choice.goal else "#bdbdbd"
            ax.add_patch(Polygon(cell.vertices(), closed=True, facecolor=face, edgecolor=edge,
                                 linewidth=2.2 if cell in choice.goal else 0.5))
        arrows(ax, movers, lw=1.0)
        fit(ax, xs, ys)

    flat = list(axes.flat)
    ax = flat[0]
    hexes(ax, set(model.chain), {})
    pts = [c.centre() for c in choice.path]
    ax.plot([p[0] for p in pts], [p[1] for p in pts], "-o", color=PATH_EDGE, ms=3, lw=1.5)
    ax.set_title(f"substrate path: cost {choice.cost}, {len(choice.path)} cells", fontsize=8)
    for ax, k in zip(flat[1:], picks):
        movers = {mv.from_cell: mv.to_cell for mv in model.rounds[k].moves} \
            if k < len(model.rounds) else {}
        hexes(ax, set(occ[k]), movers)
        ax.set_title("initial" if k == 0 else f"after round {k}", fontsize=8)
    fig.suptitle(f"walter: n = {model.n}, rounds predicted {len(model.rounds)}, "
                 f"moves {sum(len(r.moves) for r in model.rounds)}", fontsize=10)
    return save(fig, path)
