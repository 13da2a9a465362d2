"""Hexagonal fleets for benchmarks: every cell within a radius of (0, 0), moved as one."""

from __future__ import annotations

from bus.lattice import Cell


def hexagon_scenario(radius: int, shift: int, side: int = 1, program: str | None = "firmware") -> str:
    """The scenario's TOML: every cell within ``radius`` of (0, 0), the goal the same shape
    ``shift`` cells towards ``side``; the fixed module sits where both overlap. ``program``
    None: the scenario names none (the default program)."""
    origin = Cell(0, 0)
    cells = sorted({Cell(x, y) for x in range(-2 * radius, 2 * radius + 1)
                    for y in range(-2 * radius, 2 * radius + 1) if origin.distance(Cell(x, y)) <= radius},
                   key=lambda c: (c.y, c.x))
    goal = []
    for c in cells:
        for _ in range(shift):
            c = c.neighbour(side)
        goal.append(c)
    fixed = next(c for c in cells if c in set(goal))
    lines = [f'name = "hexagon-{len(cells)}"', 'profile = "v2"'] + ([f'program = "{program}"'] if program else []) + [
             f"fixed = [{fixed.x}, {fixed.y}]",
             "goal = [" + ", ".join(f"[{c.x}, {c.y}]" for c in goal) + "]"]
    for i, c in enumerate(cells, start=1):
        lines += ["[[modules]]", f"cell = [{c.x}, {c.y}]", f"id = {i}"]
    return "\n".join(lines) + "\n"
