"""Two clocks behind one interface (ARCHITECTURE principle 5).

Participants never sleep: they schedule callbacks on the clock and react to
samples the clock hands them. All callbacks run on the thread that calls
:meth:`Clock.run`, one at a time, so participants need no locks.

* :class:`WallClock` follows real time (hardware in the loop).
* :class:`VirtualClock` is a deterministic discrete-event scheduler: time jumps
  to the next pending event, and only after every sample published in the process
  has been handled (the bus puts them in the inbox as it publishes them). Ties are
  broken by scheduling order, and samples are handled in publish order, so the same
  scenario and seed give the same frames at the same sim times.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from abc import ABC, abstractmethod
from typing import Any, Callable

from .errors import HexbenchError


class ClockError(HexbenchError, RuntimeError):
    pass


class Timer:
    """Handle of a scheduled callback; ``cancel()`` makes it a no-op."""

    __slots__ = ("t_ns", "fn", "args", "cancelled")

    def __init__(self, t_ns: int, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.t_ns = t_ns
        self.fn = fn
        self.args = args
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class Clock(ABC):
    """Scheduling interface every participant uses."""

    kind: str = ""

    def __init__(self) -> None:
        self._heap: list[tuple[int, int, Timer]] = []
        self._tie = itertools.count()
        self._lock = threading.Condition()
        self._inbox: list[tuple[tuple[float, int], Callable[..., Any], tuple[Any, ...]]] = []
        self._arrivals = itertools.count()
        self._stopped = False
        self.error: BaseException | None = None
        self.started_ns = 0  # now_ns() when the clock was made (wall clocks: Unix time)

    # -- time -----------------------------------------------------------------------
    @abstractmethod
    def now_ns(self) -> int:
        """Current time of the run (ns since the clock started)."""

    def due_ns(self) -> int:
        """When the event being handled was due: :meth:`now_ns` on a virtual clock. A wall
        clock runs a timer a little late (later still on a loaded machine); stamping what
        it does with its due time keeps the program's own intervals (a 3-tick drive stays
        30 ms). Samples from elsewhere are due when they arrive."""
        return self.now_ns()

    @staticmethod
    def wall_ns() -> int:
        return time.time_ns()

    # -- scheduling (clock thread) -----------------------------------------------------
    def call_at(self, t_ns: int, fn: Callable[..., Any], *args: Any) -> Timer:
        timer = Timer(max(int(t_ns), self.now_ns()), fn, args)
        with self._lock:
            heapq.heappush(self._heap, (timer.t_ns, next(self._tie), timer))
            self._lock.notify()
        return timer

    def call_later(self, delay_ns: int, fn: Callable[..., Any], *args: Any) -> Timer:
        return self.call_at(self.now_ns() + int(delay_ns), fn, *args)

    # -- input from other threads ---------------------------------------------------------
    def post(self, fn: Callable[..., Any], *args: Any, order: tuple[float, int] | None = None) -> None:
        """Thread-safe: run ``fn(*args)`` on the clock thread at the current time.
        ``order`` sorts items that arrive while the clock settles (publish order)."""
        with self._lock:
            key = order if order is not None else (float("inf"), next(self._arrivals))
            self._inbox.append((key, fn, args))
            self._lock.notify()

    def post_foreign(self, sender: str, fn: Callable[..., Any], *args: Any) -> None:
        """Thread-safe: a sample from another process (``sender``: the name it carries, or
        ""). Handled as it comes, like :meth:`post`; a lockstep clock holds it for its
        window's end (:mod:`bus.lockstep`)."""
        self.post(fn, *args)

    # -- running ----------------------------------------------------------------------------
    def stop(self) -> None:
        with self._lock:
            self._stopped = True
            self._lock.notify()

    @property
    def stopped(self) -> bool:
        return self._stopped

    def _fire(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            fn(*args)
        except Exception as exc:  # a participant bug must not hang the run silently
            self.error = exc
            self._stopped = True
            raise

    @abstractmethod
    def run(self, *, until_ns: int | None = None, until: Callable[[], bool] | None = None,
            timeout_s: float | None = None) -> None:
        """Process events until ``until()`` holds, time passes ``until_ns``, nothing is
        left to do (virtual), ``stop()`` is called, or ``timeout_s`` wall seconds pass."""

    @abstractmethod
    def drain(self, timeout_s: float = 5.0) -> bool:
        """Handle every sample published so far to local subscribers, and whatever their
        handlers publish in turn, without running timers. False if some were still on their
        way after ``timeout_s`` wall seconds. Call it before closing a recorder."""


class VirtualClock(Clock):
    kind = "virtual"

    def __init__(self) -> None:
        super().__init__()
        self._now = 0
        self.events_run = 0
        #: the ``until_ns`` of the run in progress (None: none), for an engine that runs ahead
        #: of the timers in windows (module_sim.core): it must not pass it
        self.until_ns: int | None = None

    def now_ns(self) -> int:
        return self._now

    def next_due_ns(self) -> int | None:
        """When the next timer is due (None: no timer): how far an engine's window may run."""
        heap = self._heap
        while heap and heap[0][2].cancelled:
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    def inbox_waiting(self) -> bool:
        """Whether samples posted at this instant wait to be handled (before time moves on):
        an engine that runs ahead in windows (module_sim.core) must let them in first."""
        return bool(self._inbox)

    def advance_to(self, t_ns: int) -> None:
        """Move time on to ``t_ns`` inside a timer: an engine that ran a window of events up
        to there (never past :meth:`next_due_ns` or the run's ``until_ns``)."""
        if t_ns > self._now:
            self._now = t_ns

    def call_at(self, t_ns: int, fn: Callable[..., Any], *args: Any) -> Timer:
        # Only the clock thread schedules (other threads ``post``), and nobody waits for a
        # timer to be added: no lock, no notify.
        now = self._now
        t = int(t_ns)
        timer = Timer(t if t > now else now, fn, args)
        heapq.heappush(self._heap, (timer.t_ns, next(self._tie), timer))
        return timer

    def call_later(self, delay_ns: int, fn: Callable[..., Any], *args: Any) -> Timer:
        return self.call_at(self._now + int(delay_ns), fn, *args)

    def _settle(self) -> None:
        """Handle the inbox in publish order, and what those handlers publish in turn."""
        while self._inbox:
            with self._lock:
                batch = sorted(self._inbox, key=lambda item: item[0])
                self._inbox.clear()
            for _, fn, args in batch:
                self._fire(fn, args)

    def drain(self, timeout_s: float = 5.0) -> bool:
        self._settle()
        return True

    def run(self, *, until_ns: int | None = None, until: Callable[[], bool] | None = None,
            timeout_s: float | None = None) -> None:
        outer, self.until_ns = self.until_ns, until_ns
        try:
            self._run(until_ns, until, timeout_s)
        finally:
            self.until_ns = outer

    def _run(self, until_ns: int | None, until: Callable[[], bool] | None, timeout_s: float | None) -> None:
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        self._stopped = False
        heap = self._heap
        pop = heapq.heappop
        while True:
            while heap and heap[0][2].cancelled:
                pop(heap)
            if not heap or heap[0][0] > self._now:
                # Time is about to move on: first every sample published so far is handled
                # (in publish order); its handlers may add work at this instant. Timers due
                # now run first, so one pass covers everything published now.
                if self._inbox:
                    self._settle()
                    continue
            if self._stopped or (until is not None and until()):
                self._settle()
                return
            if deadline is not None and time.monotonic() > deadline:
                raise ClockError(f"virtual run did not finish within {timeout_s} wall seconds")
            if not heap:
                if until_ns is not None:
                    self._now = max(self._now, until_ns)
                return
            t = heap[0][0]
            if until_ns is not None and t > until_ns:
                self._now = until_ns
                return
            timer = pop(heap)[2]
            self._now = t
            self.events_run += 1
            self._fire(timer.fn, timer.args)


class WallClock(Clock):
    kind = "wall"

    def __init__(self) -> None:
        super().__init__()
        # One time base for every process on the host: IR bursts carry their byte start
        # times, and a receiver in another process schedules them on its own clock.
        self._offset = time.time_ns() - time.monotonic_ns()
        self.started_ns = self.now_ns()
        self._due: int | None = None  # the due time of the timer running now
        # Lateness (:meth:`take_lateness`): the worst since the last take, and over the clock's life.
        self._running_since = 0  # now_ns() when run() was last entered
        self._late_timer_ns = 0
        self._late_delivery_ns = 0
        self.worst_late_ns = 0

    def post(self, fn: Callable[..., Any], *args: Any, order: tuple[float, int] | None = None) -> None:
        # In the order they come (``order`` sorts only a virtual clock's inbox); the key of
        # each is when it was posted, for its lateness.
        with self._lock:
            self._inbox.append((self.now_ns(), fn, args))
            self._lock.notify()

    def take_lateness(self) -> tuple[int, int]:
        """How late this clock ran its work since the last call, in ns: the worst timer (run
        after its due time) and the worst delivery (a sample handled after it was posted).
        Counted from when the clock was last set running if that is later: work that waited
        for the clock's owner to run it (a planner planning between its waits) did not wait
        for the machine."""
        with self._lock:
            late = self._late_timer_ns, self._late_delivery_ns
            self._late_timer_ns = self._late_delivery_ns = 0
        return late

    def due_ns(self) -> int:
        return self.now_ns() if self._due is None else self._due

    def now_ns(self) -> int:
        """Unix time in ns, advanced monotonically (the same in every process)."""
        return time.monotonic_ns() + self._offset

    def drain(self, timeout_s: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                batch = self._inbox
                self._inbox = []
            if not batch:
                return True
            for _, fn, args in batch:
                self._fire(fn, args)
            if time.monotonic() > deadline:  # a stream from elsewhere never runs dry
                return False

    def run(self, *, until_ns: int | None = None, until: Callable[[], bool] | None = None,
            timeout_s: float | None = None) -> None:
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        self._stopped = False
        since = self._running_since = self.now_ns()
        while True:
            with self._lock:
                batch = self._inbox
                self._inbox = []
            for posted, fn, args in batch:
                late = self.now_ns() - (posted if posted > since else since)
                if late > self._late_delivery_ns:
                    self._note_late(late, timer=False)
                self._fire(fn, args)
            if self._stopped or (until is not None and until()):
                return
            now = self.now_ns()
            if until_ns is not None and now >= until_ns:
                return
            with self._lock:
                while self._heap and self._heap[0][2].cancelled:
                    heapq.heappop(self._heap)
                due = self._heap[0][2] if self._heap and self._heap[0][0] <= now else None
                if due is not None:
                    heapq.heappop(self._heap)
                elif not self._inbox:
                    wait = 0.2
                    if self._heap:
                        wait = min(wait, (self._heap[0][0] - now) / 1e9)
                    if until_ns is not None:
                        wait = min(wait, (until_ns - now) / 1e9)
                    if deadline is not None:
                        left = deadline - time.monotonic()
                        if left <= 0:
                            return
                        wait = min(wait, left)
                    self._lock.wait(max(wait, 0.0))
            if due is not None:
                late = now - (due.t_ns if due.t_ns > since else since)
                if late > self._late_timer_ns:
                    self._note_late(late, timer=True)
                self._due = due.t_ns
                try:
                    self._fire(due.fn, due.args)
                finally:
                    self._due = None
            elif deadline is not None and time.monotonic() > deadline:
                return

    def _note_late(self, late_ns: int, *, timer: bool) -> None:
        with self._lock:
            if timer:
                self._late_timer_ns = max(self._late_timer_ns, late_ns)
            else:
                self._late_delivery_ns = max(self._late_delivery_ns, late_ns)
            self.worst_late_ns = max(self.worst_late_ns, late_ns)


def make_clock(kind: str) -> Clock:
    if kind == "virtual":
        return VirtualClock()
    if kind == "wall":
        return WallClock()
    raise ValueError(f"unknown clock {kind!r}: expected 'virtual' or 'wall'")
