"""Progress of the long commands: a bar under the printed lines on a terminal (rich), plain lines
elsewhere (pipes, CI logs), so a run never goes quiet.

``run``: each bring-up phase and planner line as it comes (with its sim time), and once the plan
is known a bar of moves n/N with the wall time left; ``replay --to-bus``: frames sent of all.
"""

from __future__ import annotations

import sys
import time
from typing import Any, Callable, TextIO

from bus.messages import PlannerProgress

PLAIN_EVERY_S = 5.0  # a plain progress line at most this often


class Progress:
    """Lines and one bar. Use as a context manager; :meth:`say` prints a line, :meth:`update`
    moves the bar (``total`` None: the phase has no known size)."""

    def __init__(self, *, stream: TextIO | None = None, bar: bool | None = None,
                 unit: str = "step") -> None:
        """``unit``: what the planner's progress counts in (``planners.progress_unit``)."""
        self.stream = stream or sys.stdout
        self.bar = self.stream.isatty() if bar is None else bar
        self.unit = unit
        self._rich: Any = None
        self._task: Any = None
        self._last_plain = 0.0
        self._last_plain_text = ""

    def __enter__(self) -> "Progress":
        if self.bar:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn
            from rich.progress import Progress as RichProgress
            from rich.progress import SpinnerColumn, TextColumn, TimeRemainingColumn
            self._rich = RichProgress(
                SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("left"), TimeRemainingColumn(),
                console=Console(file=self.stream), transient=True)
            self._rich.start()
            self._task = self._rich.add_task("starting", total=None)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._rich is not None:
            self._rich.stop()
            self._rich = None

    def say(self, line: str) -> None:
        """Print one line (above the bar)."""
        if self._rich is not None:
            self._rich.console.print(line, markup=False, highlight=False, soft_wrap=True)
        else:
            print(line, file=self.stream, flush=True)

    def update(self, description: str, done: int, total: int | None) -> None:
        """The bar's state; without a bar, a plain line at most every :data:`PLAIN_EVERY_S` (and
        at the end), if it says something new."""
        if self._rich is not None:
            self._rich.update(self._task, description=description, completed=done, total=total)
            return
        now = time.monotonic()
        text = f"progress: {description} {done}/{total}" if total else f"progress: {description}"
        if text != self._last_plain_text and (now - self._last_plain >= PLAIN_EVERY_S or (total and done >= total)):
            self._last_plain, self._last_plain_text = now, text
            self.say(text)

    def phase(self, text: str) -> None:
        """What is going on while its size is unknown (the bar's text; plain output has the line)."""
        if self._rich is not None:
            self._rich.update(self._task, description=text[:60], completed=0, total=None)

    # -- a run's planner progress, from the bus -----------------------------------------------
    def on_planner_progress(self, key: str, payload: bytes) -> None:
        """Bus handler of ``planner/progress``: moves n/N once the plan is known."""
        try:
            p = PlannerProgress.from_json(payload)
        except (ValueError, KeyError, TypeError):
            return
        if p.planned and self._rich is not None:  # plain output: the planner's own lines say it
            self.update(f"moves ({self.unit} {p.step})", p.moves, p.planned)


def phase_sayer(progress: Progress) -> Callable[[str], None]:
    """A ``say`` for the planner service: every line printed, and the bar's description follows
    the bring-up's phases until the moves start."""
    def say(line: str) -> None:
        progress.say(line)
        if line.startswith(("bring-up:", "planning:", "plan:")):
            progress.phase(line.split(":", 1)[1].strip())
    return say
