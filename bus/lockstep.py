"""One virtual clock across processes: conservative lockstep windows over zenoh.

A virtual run is deterministic in one process (``bus.session`` isolates it). Spread over
processes, each participant (a shard of a fleet, the planner's process, a recorder) keeps
its own :class:`LockstepClock` and they move together, window by window, as conservative
parallel discrete-event simulation does:

* Window ``k`` is sim time ``[k*W, (k+1)*W)``. A participant runs its events of the window,
  then says so on ``hexbot/<fleet>/@lockstep/window/<name>`` and waits until every other
  participant has said the same.
* Its samples of the window went out before that word, on the same reliable lane of the same
  session, so when the last word arrives every sample another process put in window ``k`` is
  here too: held, not handled. They are handled at the window's end, ``(k+1)*W``, before
  anything else there, by sender name, then in the order each sender put them: an order that
  depends on the run alone, not on thread timing. A peer that crossed first may already be
  sending its samples of window ``k+1``: they arrive behind its word on ``k``, so they are
  held for the next boundary (handled at ``(k+1)*W`` they would come before their time, or
  not, as the threads went).
* **The lookahead contract.** A sample that crosses processes is handled up to one window
  after it was put. So what it causes must lie at least ``W`` after it (the IR medium's light
  has a byte time: 33.3 ms at 300 baud), and its handler must act on the times it carries,
  not on the time it is handled. Then the run gives the frames the one-process run gives.
* **A participant that decodes runs behind.** Light that several processes send to one
  receiver collides there, and a byte's value is final only once every byte overlapping it is
  known, which a window later may be after its stop bit. A participant given a lag of one
  window (``lags``) ends its window ``k`` only with the others' words on ``k + 1``: their
  samples of window ``k + 1`` are handled at its start, before their time (light acts on the
  times it carries), and its own reach them two windows late at most. With windows of at most
  half a byte time, light still arrives before its first byte ends either way.
* **Liveness.** Every participant holds a zenoh liveliness token. One that vanishes (its
  process killed, its link cut) ends the others at the barrier of the window they are in,
  with :class:`PeerLost` naming it; one that stays silent ends them after ``timeout_s``.
* The clock does it all: :meth:`LockstepClock.run` crosses a window's end only through the
  barrier, so code that drives a clock (the planner's ``clock.run(until=...)``) runs
  unchanged. All participants stop at the same boundary: the end of the window in which
  one of them called :meth:`Lockstep.finish` (one that runs behind or ahead: at the end of
  its own window of that moment).

The cost per window is one small sample from each participant to each other and a wait for
the slowest: with ``W`` = 16.7 ms and a fleet running near real time that is ~60 barriers per
wall second.
"""

from __future__ import annotations

import atexit
import json
import threading
import time
from typing import Any, Callable, Iterable

import zenoh

from .clock import ClockError, VirtualClock
from .keys import ROOT, check_chunk
from .transport import Bus


#: How long a peer whose token went may still have its last word on the way.
GONE_GRACE_S = 0.5


class PeerLost(ClockError):
    """A participant of a lockstep run left it before the end."""


class LockstepClock(VirtualClock):
    """A :class:`VirtualClock` whose samples from other processes wait for the window's
    barrier (:class:`Lockstep`) instead of being handled as they arrive."""

    def __init__(self) -> None:
        super().__init__()
        # sender -> its samples in arrival order, with a (None, (k,)) mark where its word on
        # window k came: what is before the mark it put in window k or earlier
        self._held: dict[str, list[tuple[Callable[..., Any] | None, tuple[Any, ...]]]] = {}
        self._speakers: set[str] = set()  # senders that say words: participants, not bystanders
        self.lockstep: Lockstep | None = None  # set by Lockstep: until then, a plain virtual clock
        self.ended = False  # every participant stopped at a barrier: nothing more will run
        #: called with each boundary's time once the samples held for it are handled: work
        #: that needs a window's samples from everywhere, in time order (the world's physics)
        self.at_boundary: list[Callable[[int], None]] = []

    def run(self, *, until_ns: int | None = None, until: Callable[[], bool] | None = None,
            timeout_s: float | None = None) -> None:
        """As :meth:`VirtualClock.run`, window by window: time crosses a window's end only
        at the barrier, with every peer. Returns when ``until()`` holds (mid-window too),
        ``until_ns`` is reached, the participants stopped (:meth:`Lockstep.finish`, or a
        peer's), or ``timeout_s`` wall seconds passed (``ClockError``)."""
        step = self.lockstep
        if step is None:
            return super().run(until_ns=until_ns, until=until, timeout_s=timeout_s)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        step.wait_for_peers()
        while not self.ended:
            end = (step.window + 1) * step.window_ns
            limit = end - 1 if until_ns is None else min(end - 1, until_ns)
            left = None if deadline is None else max(deadline - time.monotonic(), 0.001)
            super().run(until_ns=limit, until=until, timeout_s=left)
            if (until is not None and until()) or (until_ns is not None and self._now >= until_ns):
                return
            if self._stopped and not step.stopping:
                return  # stop(): this participant pauses; finish() ends the run for all
            if deadline is not None and time.monotonic() > deadline:
                raise ClockError(f"lockstep run did not finish within {timeout_s} wall seconds")
            step.cross()

    def post_foreign(self, sender: str, fn: Callable[..., Any], *args: Any) -> None:
        with self._lock:
            self._held.setdefault(sender, []).append((fn, args))

    def mark_window(self, sender: str, window: int) -> None:
        """``sender``'s word on ``window`` came (on the thread that holds its samples, in the
        order it sent them): what it sent before belongs to that window or an earlier one."""
        with self._lock:
            self._held.setdefault(sender, []).append((None, (window,)))
            self._speakers.add(sender)

    def release(self, at_ns: int, window: int | None = None, ahead: dict[str, int] | None = None) -> int:
        """Time moves to ``at_ns`` (a window boundary) and the held samples are handled
        there, by sender, each sender's in arrival order: of a sender that said a word, those
        before its word on ``window`` plus its ``ahead`` (windows it runs ahead of this
        participant; its later ones wait for their own boundary); of one that says none, all.
        Returns how many."""
        taken: dict[str, list[tuple[Callable[..., Any], tuple[Any, ...]]]] = {}
        ahead = ahead or {}
        with self._lock:
            for sender, items in self._held.items():
                upto = len(items)
                if window is not None and sender in self._speakers:
                    due = window + ahead.get(sender, 0)
                    marks = [i for i, (fn, args) in enumerate(items) if fn is None and args[0] <= due]
                    upto = marks[-1] + 1 if marks else 0
                taken[sender] = [item for item in items[:upto] if item[0] is not None]
                del items[:upto]
            self._held = {sender: items for sender, items in self._held.items() if items}
        self._now = max(self._now, at_ns)
        n = 0
        for sender in sorted(taken):
            for fn, args in taken[sender]:
                self._inbox.append(((float(n), 0), fn, args))
                n += 1
        self._settle()
        for fn in self.at_boundary:
            fn(at_ns)
        self._settle()
        return n


class Lockstep:
    """One participant's side of a lockstep run (see the module's docstring).

    Make the participant's subscriptions on ``bus`` first: a peer starts sending once it sees
    this participant's token, which zenoh delivers after the subscriptions declared before it.
    """

    def __init__(self, bus: Bus, name: str, peers: Iterable[str], window_ns: int, *,
                 timeout_s: float = 60.0, lags: dict[str, int] | None = None) -> None:
        if not isinstance(bus.clock, LockstepClock):
            raise TypeError("a lockstep participant needs a LockstepClock")
        if window_ns <= 0:
            raise ValueError(f"window {window_ns} ns: must be positive")
        self.bus, self.clock = bus, bus.clock
        self.name = check_chunk(name, "participant")
        self.peers = sorted({check_chunk(p, "participant") for p in peers} - {self.name})
        self.window_ns = window_ns
        self.timeout_s = timeout_s
        # how many windows each peer runs ahead of this participant (lags: windows behind)
        lag = lags or {}
        self.ahead = {p: lag.get(self.name, 0) - lag.get(p, 0) for p in self.peers}
        self.window = 0  # the window this participant is in
        self.stopping = False
        self.released = 0  # samples from elsewhere handled at boundaries
        self._cond = threading.Condition()
        self._said: dict[str, int] = {}  # peer -> the last window it finished
        self._stops: dict[str, int] = {}  # peer -> the window after which it stops
        self._present: set[str] = set()
        self._gone: set[str] = set()
        bus.sender = self.name
        # The word is a bus sample: it travels behind this participant's other samples and
        # arrives through the same subscriber, on the same zenoh thread, so when it is seen
        # they have all been taken (zenoh runs each subscriber's callbacks on its own thread:
        # a word on a subscriber of its own could overtake them).
        self._word_key = f"{bus.keys.root}/lockstep/window/{self.name}"
        bus.subscribe(f"{bus.keys.root}/lockstep/window/*", lambda k, p: None, who="lockstep")
        bus.on_control(f"{bus.keys.root}/lockstep/window/", self._on_word)
        live = f"{ROOT}/{bus.keys.fleet}/@lockstep/live"
        session = bus.session
        self._alive = session.liveliness().declare_subscriber(f"{live}/*", self._on_live, history=True)
        self._token = session.liveliness().declare_token(f"{live}/{self.name}")
        self.closed = False
        self._joined = False
        bus.clock.lockstep = self
        # before the bus's own (atexit runs last in, first out): zenoh objects left to the
        # interpreter's finalization can hang it
        atexit.register(self.close)

    # -- zenoh threads ---------------------------------------------------------------------
    def _on_word(self, sender: str, key: str, payload: bytes) -> None:
        who = key.rsplit("/", 1)[-1]
        try:
            d = json.loads(payload)
            k = int(d["window"])
        except (ValueError, KeyError, TypeError):
            return  # not a word of ours: the barrier waits for a good one
        # behind every sample the sender put in window k and before any of k+1 (one lane)
        self.clock.mark_window(sender or who, k)
        with self._cond:
            self._said[who] = max(self._said.get(who, -1), k)
            if d.get("stop"):
                self._stops.setdefault(who, k)
            self._cond.notify_all()

    def _on_live(self, sample: zenoh.Sample) -> None:
        who = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._cond:
            if sample.kind == zenoh.SampleKind.DELETE:
                self._present.discard(who)
                self._gone.add(who)
            else:
                self._present.add(who)
            self._cond.notify_all()

    # -- the clock thread ------------------------------------------------------------------
    def wait_for_peers(self, timeout_s: float | None = None) -> None:
        """Return once every peer is there (``ClockError`` naming the missing ones if not)."""
        if self._joined:
            return
        timeout = self.timeout_s if timeout_s is None else timeout_s
        with self._cond:
            if not self._cond.wait_for(lambda: self._present >= set(self.peers), timeout):
                missing = sorted(set(self.peers) - self._present)
                raise ClockError(f"lockstep {self.name}: {', '.join(missing)} did not join within "
                                 f"{timeout:g} s")
        self._joined = True

    def cross(self) -> None:
        """The barrier at the end of the current window (its events all run): say so, wait
        for every peer, handle what they sent at the boundary; the run ends there if this
        participant or a peer asked to."""
        k = self.window
        end = (k + 1) * self.window_ns
        self.bus.put_remote(self._word_key, json.dumps(
            {"window": k, "stop": self.stopping, "sim_time_ns": end}).encode())
        others_stop = self._barrier(k)
        self.released += self.clock.release(end, k, self.ahead)
        self.window = k + 1
        if self.stopping or others_stop:
            self.clock.ended = True

    def finish(self) -> None:
        """End the run for every participant at the end of the current window (this one's
        events of it still run)."""
        self.stopping = True
        self.clock._stopped = False
        self.clock.run()

    def run(self, *, until_ns: int | None = None) -> None:
        """Run every window (and its barrier) until all participants stop; with ``until_ns``
        (a window boundary), stop them all there."""
        if until_ns is None:
            self.clock.run()
        else:
            self.clock.run(until_ns=until_ns - 1)
            self.finish()

    def _barrier(self, k: int) -> bool:
        """Wait for every peer's word on window ``k`` (plus the windows it runs ahead); whether
        one of them stops after it."""
        deadline = time.monotonic() + self.timeout_s
        gone_since: float | None = None
        ahead = self.ahead
        with self._cond:
            while True:
                behind = [p for p in self.peers if self._said.get(p, -1) < k + ahead[p]]
                if not behind:
                    return any(s <= k + ahead.get(p, 0) for p, s in self._stops.items())
                gone = [p for p in behind if p in self._gone]
                if gone and gone_since is None:
                    # a finished peer's token may go before its last word is taken here
                    gone_since = time.monotonic()
                if gone and time.monotonic() - gone_since >= GONE_GRACE_S:
                    raise PeerLost(f"lockstep: {', '.join(gone)} left the run in window {k} (sim "
                                   f"{k * self.window_ns / 1e9:.3f}-{(k + 1) * self.window_ns / 1e9:.3f} s): "
                                   "its process ended or its link broke")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise ClockError(f"lockstep: no word from {', '.join(behind)} on window {k} within "
                                     f"{self.timeout_s:g} s")
                self._cond.wait(min(left, GONE_GRACE_S / 4) if gone else left)

    def close(self) -> None:
        """Leave the run: every word said reaches the peers before the token goes (a peer
        must not take a finished participant for a lost one)."""
        if self.closed:
            return
        self.closed = True
        if not self.bus.closed:
            self.bus.flush()
        for thing in (self._token, self._alive):
            try:
                thing.undeclare()
            except Exception:  # the session may be closing already
                pass
