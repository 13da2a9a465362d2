"""The participant's view of the bus (ARCHITECTURE principle 1).

How a sample travels:

* **Inside a process**, the :class:`Bus` objects on one zenoh session share a hub: a table of
  their subscriptions (exact keys in a dict, wildcards matched once per key and cached).
  ``put`` hands the sample to every matching handler through the clock's inbox, on the
  clock's thread, in publish order then subscription order: no zenoh round trip, no thread
  per subscriber, no waiting for deliveries. A virtual clock handles the inbox before time
  moves on, so a run is deterministic.
* **Across processes and hosts**, every sample is also put on zenoh, for remote
  subscribers only; samples from elsewhere arrive through one wildcard subscriber
  (``hexbot/**``, remote origin only) and reach the same handlers through the inbox.
  Threads do not grow with the fleet.
* **In batches**, ``put_batch`` does what ``put`` does for each of its samples, in order, at a
  fraction of the cost: a handler registered with ``subscribe_batch`` gets all the samples of
  a batch that match it in one call, through one inbox post; other processes get the batch as
  one zenoh sample on ``hexbot/@batch/<fleet>`` (:func:`pack_batch`), which their hub unpacks
  so that every handler there sees each sample under its own key, in order.
* **Packed**, ``put_packed`` takes a batch already in :func:`pack_batch`'s bytes (rendered in
  C): the same effect as ``put_batch`` of its samples, but a handler registered with
  ``subscribe_batch(..., packed=True)`` gets such bytes, and the samples are unpacked only
  for the handlers that take them as ``(key, payload)`` (here and in other processes).
"""

from __future__ import annotations

import atexit
import itertools
import json
import struct
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

import zenoh

from .clock import Clock, make_clock
from .codec import Frame
from .envelope import SCHEMA_VERSION, Envelope
from .errors import UsageError
from .keys import ROOT, Keys, check_chunk
from .session import SessionOptions, open_session

Handler = Callable[[str, bytes], None]
#: A batch handler's argument: ``(key, payload)`` of every sample of a batch that matched it, in order.
Samples = Sequence[tuple[str, bytes]]
BatchHandler = Callable[[list[tuple[str, bytes]]], None]
#: A packed batch handler's argument: the samples that matched it, in :func:`pack_batch`'s bytes.
PackedHandler = Callable[[bytes], None]

#: The key of the flush barrier (a verbatim ``@`` chunk: no ``hexbot/**`` matches it), and how
#: long a closing session waits for the answers of the processes that subscribe to it.
FLUSH_KEY, FLUSH_TIMEOUT_S = f"{ROOT}/@flush", 30.0
#: Where a batch travels between processes: ``hexbot/@batch/<fleet>`` (verbatim too, so the
#: samples it carries are never seen twice by a ``hexbot/**`` subscriber).
BATCH_PREFIX = f"{ROOT}/@batch"
_BATCH_ITEM = struct.Struct("<HI")  # key length, payload length (then the key, then the payload)


def pack_batch(items: Samples) -> bytes:
    """A batch on the wire: per sample, its key's UTF-8 length (u16, little-endian), its
    payload's length (u32), the key, the payload; nothing else (docs/bus.md)."""
    parts: list[bytes] = []
    add = parts.extend
    pack = _BATCH_ITEM.pack
    try:
        for key, payload in items:
            k = key.encode()
            add((pack(len(k), len(payload)), k, payload))
    except struct.error:
        raise ValueError("a batch key must be shorter than 64 KiB and a payload than 4 GiB") from None
    return b"".join(parts)


def unpack_batch(data: bytes) -> list[tuple[str, bytes]]:
    """The samples of :func:`pack_batch`'s bytes; ``ValueError`` if they are not such bytes."""
    out: list[tuple[str, bytes]] = []
    add = out.append
    mv = memoryview(data)
    for off, klen, end in _samples(data):
        start = off + 6
        add((str(mv[start:start + klen], "utf-8"), data[start + klen:end]))
    return out


def batch_keys(data: bytes) -> tuple[list[bytes], list[int]]:
    """The keys (UTF-8, not decoded) of :func:`pack_batch`'s bytes and where each sample ends
    (the next starts there), without copying a payload; ``ValueError`` as :func:`unpack_batch`."""
    keys: list[bytes] = []
    ends: list[int] = []
    add, end_at = keys.append, ends.append
    for off, klen, end in _samples(data):
        add(data[off + 6:off + 6 + klen])
        end_at(end)
    return keys, ends


def _samples(data: bytes) -> Iterator[tuple[int, int, int]]:
    """Per sample of a packed batch: where it starts, its key's length, where it ends."""
    unpack = _BATCH_ITEM.unpack_from
    off, end = 0, len(data)
    while off < end:
        if end - off < 6:
            raise ValueError(f"batch cut short: {end - off} bytes where a sample header (6) belongs")
        klen, plen = unpack(data, off)
        nxt = off + 6 + klen + plen
        if nxt > end or not klen:
            raise ValueError(f"batch sample at byte {off} runs past the end ({nxt} > {end}) or has no key")
        yield off, klen, nxt
        off = nxt


def _sample_at(data: bytes, key: bytes, start: int, end: int) -> tuple[str, bytes]:
    """The sample of packed ``data`` in ``[start, end)`` whose key is ``key``."""
    return key.decode(), data[start + 6 + len(key):end]


def select_samples(data: bytes, ends: list[int], keep: Sequence[bool]) -> bytes:
    """The samples of packed ``data`` (sample ``i`` ends at ``ends[i]``) where ``keep`` is
    true, packed: runs of kept samples are copied whole."""
    parts: list[bytes] = []
    run: int | None = None  # where the current run of kept samples starts
    prev = 0
    for i, k in enumerate(keep):
        if k:
            if run is None:
                run = prev
        elif run is not None:
            parts.append(data[run:prev])
            run = None
        prev = ends[i]
    if run is not None:
        parts.append(data[run:prev])
    return b"".join(parts)


@dataclass(eq=False)
class Subscription:
    """One handler on one key expression (returned by :meth:`Bus.subscribe`)."""

    keyexpr: zenoh.KeyExpr
    handler: Handler
    bus: "Bus"
    index: int  # subscription order in the hub: ties of one sample are handled in it
    hub: "_Hub"
    who: str  # the participant, for its bad-sample events
    batch: bool = False  # handler(list of (key, payload)), see Bus.subscribe_batch
    packed: bool = False  # a batch handler that takes pack_batch's bytes instead
    active: bool = True

    @property
    def clock(self) -> Clock:
        return self.bus.clock

    def undeclare(self) -> None:
        """Stop delivering to the handler."""
        if self.active:
            self.active = False
            self.hub.remove(self)


class _Hub:
    """In-process delivery for the buses of one zenoh session."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.exact: dict[str, list[Subscription]] = {}  # by canonical key
        self.wild: list[Subscription] = []
        self.cache: dict[str, tuple[Subscription, ...]] = {}
        self.order = itertools.count()  # publish order of every sample put here
        self.index = itertools.count()
        self.remote: dict[str, Any] = {}  # zenoh subscribers for samples from elsewhere
        self.flush_answer: Any = None  # the queryable of :meth:`flush`, with the first of them
        self.sent = False  # whether anything was put on zenoh through this session
        self.attachment: bytes | None = None  # Bus.sender
        self.control: list[tuple[str, Callable[[str, str, bytes], None]]] = []  # see Bus.on_control
        self.users = 0

    def add(self, sub: Subscription) -> None:
        canon = str(sub.keyexpr)
        if "*" in canon or "$" in canon:
            self.wild.append(sub)
        else:
            self.exact.setdefault(canon, []).append(sub)
        self.cache.clear()
        # samples from elsewhere: one wildcard subscriber for every fleet (or one per key
        # expression outside them), so the threads zenoh runs do not grow with subscriptions
        scope = f"{ROOT}/**" if canon.startswith(ROOT + "/") else canon
        if scope not in self.remote:
            self.remote[scope] = self.session.declare_subscriber(
                scope, self._from_elsewhere, allowed_origin=zenoh.Locality.REMOTE)
        if BATCH_PREFIX not in self.remote:  # batches of every fleet: unpacked, then matched here
            self.remote[BATCH_PREFIX] = self.session.declare_subscriber(
                f"{BATCH_PREFIX}/*", self._batch_from_elsewhere, allowed_origin=zenoh.Locality.REMOTE)
        if self.flush_answer is None:
            # a flush query arrives behind every sample its sender put before it: answering it
            # says they are all in this process (on their clocks' inboxes)
            self.flush_answer = self.session.declare_queryable(FLUSH_KEY, lambda q: q.reply(FLUSH_KEY, b""))

    def remove(self, sub: Subscription) -> None:
        canon = str(sub.keyexpr)
        group = self.wild if sub in self.wild else self.exact.get(canon, [])
        if sub in group:
            group.remove(sub)
        self.cache.clear()

    def matches(self, key: str) -> tuple[Subscription, ...]:
        subs = self.cache.get(key)
        if subs is None:
            found = list(self.exact.get(key, ()))
            if self.wild:
                ke = zenoh.KeyExpr(key)
                found += [s for s in self.wild if s.keyexpr.intersects(ke)]
            subs = self.cache[key] = tuple(sorted(found, key=lambda s: s.index))
        return subs

    def routes(self, keys: list[bytes]) -> list[tuple[Subscription, ...]]:
        """The subscriptions of each key of a packed batch (UTF-8 keys, cached as they are:
        bytes and str keys never collide in ``cache``); ``ValueError`` for a key that is not
        UTF-8, zenoh's error for one that is no key expression."""
        cache = self.cache
        routes = list(map(cache.get, keys))
        if None in routes:
            for i, (k, subs) in enumerate(zip(keys, routes)):
                if subs is None:
                    subs = cache.get(k)
                    if subs is None:
                        subs = cache[k] = self.matches(k.decode())
                    routes[i] = subs
        return routes  # type: ignore[return-value]

    def _from_elsewhere(self, sample: zenoh.Sample) -> None:
        """A zenoh thread: a sample another process put; its handlers run on their clocks
        in arrival order."""
        key = str(sample.key_expr)
        data = sample.payload.to_bytes()
        att = sample.attachment
        sender = att.to_bytes().decode("utf-8", "replace") if att is not None else ""
        for prefix, fn in self.control:
            if key.startswith(prefix):
                fn(sender, key, data)
                return
        for sub in self.matches(key):
            if sub.batch:
                sub.clock.post_foreign(sender, _deliver_foreign_batch, sub,
                                       pack_batch(((key, data),)) if sub.packed else [(key, data)])
            else:
                sub.clock.post_foreign(sender, _deliver_foreign, sub, key, data)

    def _batch_from_elsewhere(self, sample: zenoh.Sample) -> None:
        """A zenoh thread: a batch another process put (:meth:`Bus.put_batch`,
        :meth:`Bus.put_packed`). Each of its samples reaches this process's handlers as if it
        had come alone, in order (control prefixes included); a batch handler gets its samples
        of the batch in one call, after the per-sample handlers of the batch (or before a
        control sample in it). When only batch handlers match, the batch is not split into
        samples, and a packed handler that matches every key gets the bytes as they came."""
        key = str(sample.key_expr)
        data = sample.payload.to_bytes()
        att = sample.attachment
        sender = att.to_bytes().decode("utf-8", "replace") if att is not None else ""
        try:
            keys, ends = batch_keys(data)
        except ValueError as exc:
            self._bad_batch(sender, key, data, exc)
            return
        control = self.control
        prefixes = tuple(p.encode() for p, _ in control)
        if not control or not any(k.startswith(prefixes) for k in keys):
            try:
                routes = self.routes(keys)
            except Exception:  # a key that is no key expression: sample by sample, below
                routes = None
            if routes is not None:
                distinct = set(routes)
                subs = {sub for group in distinct for sub in group}
                if all(sub.batch for sub in subs):  # batch handlers only: whole
                    items = None
                    for sub in sorted(subs, key=lambda s: s.index):
                        whole = all(sub in group for group in distinct)
                        if sub.packed:
                            mine: Any = data if whole else select_samples(data, ends, [sub in g for g in routes])
                        else:
                            items = unpack_batch(data) if items is None else items  # framed: cannot fail
                            mine = items if whole else [item for item, g in zip(items, routes) if sub in g]
                        sub.clock.post_foreign(sender, _deliver_foreign_batch, sub, mine)
                    return
        try:
            items = unpack_batch(data)
        except ValueError as exc:  # a key that is not UTF-8
            self._bad_batch(sender, key, data, exc)
            return
        groups: dict[Subscription, list[tuple[str, bytes]]] = {}
        matches = self.matches
        for k, payload in items:
            if control and self._control(sender, k, payload, groups):
                groups = {}
                continue
            try:
                subs = matches(k)
            except Exception as exc:  # not a key expression: the sender is wrong
                self._bad_batch(sender, key, payload, exc, item=k)
                continue
            for sub in subs:
                if sub.batch:
                    group = groups.get(sub)
                    if group is None:
                        group = groups[sub] = []
                    group.append((k, payload))
                else:
                    sub.clock.post_foreign(sender, _deliver_foreign, sub, k, payload)
        self._post_groups(sender, groups)

    def _control(self, sender: str, key: str, payload: bytes,
                 groups: dict[Subscription, list[tuple[str, bytes]]]) -> bool:
        """A control sample inside a batch goes to its function, after the samples before it
        are on their clocks (``groups`` posted); False if ``key`` is not one."""
        for prefix, fn in self.control:
            if key.startswith(prefix):
                self._post_groups(sender, groups)
                fn(sender, key, payload)
                return True
        return False

    @staticmethod
    def _post_groups(sender: str, groups: dict[Subscription, list[tuple[str, bytes]]]) -> None:
        for sub, group in groups.items():
            sub.clock.post_foreign(sender, _deliver_foreign_batch, sub, pack_batch(group) if sub.packed else group)

    def _bad_batch(self, sender: str, key: str, data: bytes, exc: Exception, item: str | None = None) -> None:
        """A batch (or a sample in one) that cannot be unpacked: a ``bad-sample`` event of
        ``bus``, published on the clock of a bus of the batch's fleet (any bus if none)."""
        fleet = key.rsplit("/", 1)[-1]
        subs = [s for group in (*self.exact.values(), self.wild) for s in group if s.active]
        if not subs:
            return
        sub = next((s for s in subs if s.bus.keys.fleet == fleet), subs[0])
        reason = f"{type(exc).__name__}: {exc}"[:300]
        sub.clock.post_foreign(sender, _bad_sample, sub.bus, "bus", item or key, reason, data)

    def flush(self, timeout_s: float = FLUSH_TIMEOUT_S) -> None:
        """Return once every process subscribed here holds what this session put: a query
        behind the samples on the same reliable, same-priority lane, answered by each of them.
        Closing a session drops what its links still queue for a slow subscriber."""
        replies = self.session.get(FLUSH_KEY, target=zenoh.QueryTarget.ALL,
                                   consolidation=zenoh.ConsolidationMode.NONE,
                                   congestion_control=zenoh.CongestionControl.BLOCK,
                                   allowed_destination=zenoh.Locality.REMOTE, timeout=timeout_s)
        for _ in replies:  # ends when all answered, or at the timeout
            pass

    def close(self) -> None:
        if self.flush_answer is not None:
            self.flush_answer.undeclare()
            self.flush_answer = None
        for sub in self.remote.values():
            try:
                sub.undeclare()
            except Exception:
                pass
        self.remote.clear()


def _deliver(sub: Subscription, key: str, data: bytes) -> None:
    if sub.active:
        sub.handler(key, data)


def _deliver_batch(sub: Subscription, items: list[tuple[str, bytes]]) -> None:
    if sub.active:
        sub.handler(items)


def _bad_sample(bus: "Bus", who: str, key: str, reason: str, data: bytes) -> None:
    if not bus.closed:
        bus.event(who, "bad-sample", key=bus.keys.relative(key), reason=reason, bytes=data[:256].hex(),
                  size=len(data))


def _deliver_foreign_batch(sub: Subscription, items: Any) -> None:
    """Samples of a batch from another process, for a batch handler (packed or not): one it
    cannot take is a ``bad-sample`` event (for the first of them; ``items``: how many the call had)."""
    if not sub.active:
        return
    try:
        sub.handler(items)
    except Exception as exc:
        if sub.packed:
            items = unpack_batch(items)
        key, data = items[0]
        _bad_sample(sub.bus, sub.who, key, f"{type(exc).__name__}: {exc} ({len(items)} samples)"[:300], data)


def _deliver_foreign(sub: Subscription, key: str, data: bytes) -> None:
    """A sample from another process: one that its handler cannot take (not JSON, a field
    missing, a value out of range) is an ``event/<participant>`` ``bad-sample``, and the
    participant goes on. (A local sample's failure is a bug of this process: it stops the
    run with the clock's error.)"""
    if not sub.active:
        return
    try:
        sub.handler(key, data)
    except Exception as exc:  # errors are data: the sender is wrong, not this participant
        _bad_sample(sub.bus, sub.who, key, f"{type(exc).__name__}: {exc}"[:300], data)


def participant(handler: Callable[..., Any]) -> str:
    """A name for the owner of ``handler`` in event keys: its ``name`` (``m3``, ``pc``) or its
    class (``world``, ``mechanics``); ``bus`` for a plain function."""
    owner = getattr(handler, "__self__", None)
    name = getattr(owner, "name", None)
    try:
        return check_chunk(name) if isinstance(name, str) else type(owner).__name__.lower() \
            if owner is not None else "bus"
    except ValueError:
        return type(owner).__name__.lower()


_HUBS: dict[int, _Hub] = {}  # by id(session)


class Bus:
    """A participant's handle on the bus: publish, subscribe, events; one zenoh session,
    shared by the buses of a process that pass it (``session=``)."""

    def __init__(self, clock: Clock, fleet: str = "default", *,
                 session: zenoh.Session | None = None, options: SessionOptions | None = None) -> None:
        self.clock = clock
        self.keys = Keys(fleet)
        self._own_session = session is None
        self.session = session if session is not None else open_session(options)
        hub = _HUBS.get(id(self.session))
        if hub is None:
            hub = _HUBS[id(self.session)] = _Hub(self.session)
        hub.users += 1
        self._hub = hub
        self._subs: list[Subscription] = []
        self._publishers: dict[str, Any] = {}
        self._seq: dict[str, int] = {}
        self._frame_keys: dict[tuple[Any, str], str] = {}  # (link, src) -> its frame key
        self._batch_key = f"{BATCH_PREFIX}/{self.keys.fleet}"
        self.published = 0
        self.closed = False
        atexit.register(self.close)

    @property
    def sender(self) -> str | None:
        """The name the samples of this process's session carry to other processes (a zenoh
        attachment), for receivers that order them by sender (:mod:`bus.lockstep`); None:
        no name. Shared by every bus on the session."""
        return None if self._hub.attachment is None else self._hub.attachment.decode()

    @sender.setter
    def sender(self, name: str | None) -> None:
        self._hub.attachment = None if name is None else name.encode()

    # -- publishing ----------------------------------------------------------------------
    def put(self, key: str, payload: bytes) -> None:
        """Publish raw bytes: to this process's subscribers at once (through their clocks'
        inboxes, in publish order), and through zenoh to everyone else's."""
        if self.closed:
            return
        hub = self._hub
        order = next(hub.order)
        for sub in hub.matches(key):
            if sub.batch:
                sub.clock.post(_deliver_batch, sub, pack_batch(((key, payload),)) if sub.packed else [(key, payload)],
                               order=(order, sub.index))
            else:
                sub.clock.post(_deliver, sub, key, payload, order=(order, sub.index))
        self.put_remote(key, payload)
        self.published += 1

    def put_batch(self, items: Samples) -> None:
        """Publish many samples at once: the effect of :meth:`put` for each, in order, for
        less. Per-sample handlers here get each sample as from ``put``; a batch handler
        (:meth:`subscribe_batch`) gets the ones that match it in one call, handled where its
        first sample would have been. Other processes get the batch as one zenoh sample on
        ``hexbot/@batch/<fleet>`` (:func:`pack_batch`), unpacked there sample by sample."""
        if self.closed or not items:
            return
        hub = self._hub
        keys = [item[0] for item in items]
        routes = list(map(hub.cache.get, keys))  # the subscriptions of each key, where known
        if None in routes:
            routes = [matches if matches is not None else hub.matches(key) for key, matches in zip(keys, routes)]
        distinct = set(routes)
        pub = self._publishers.get(self._batch_key) or self._publisher(self._batch_key)
        remote = pub.matching_status.matching
        data = pack_batch(items) if remote or any(sub.packed for group in distinct for sub in group) else None
        self._deliver_batch(items, routes, distinct, data, None)
        if remote:
            self.put_remote(self._batch_key, data)
        self.published += len(items)

    def put_packed(self, data: bytes) -> None:
        """:meth:`put_batch` of the samples packed in ``data`` (:func:`pack_batch`'s bytes, made
        elsewhere: the fleet core renders them in C), without unpacking them for handlers that
        take them packed (``subscribe_batch(..., packed=True)``): a packed handler matching every
        key gets ``data`` itself; samples are split out only for per-sample and unpacked batch
        handlers. Other processes get the same bytes as one zenoh sample. ``ValueError`` (and
        nothing published) if ``data`` is not such bytes."""
        if self.closed or not data:
            return
        hub = self._hub
        keys, ends = batch_keys(data)
        routes = hub.routes(keys)
        distinct = set(routes)
        subs = {sub for group in distinct for sub in group}
        if all(sub.packed for sub in subs):
            if subs:
                n = next(hub.order)
                for sub in sorted(subs, key=lambda s: s.index):
                    mine = data if all(sub in group for group in distinct) else \
                        select_samples(data, ends, [sub in group for group in routes])
                    sub.clock.post(_deliver_batch, sub, mine, order=(n, sub.index))
        elif all(sub.batch for sub in subs):
            self._put_batch_to_batches(unpack_batch(data), routes, distinct, data, ends)
        else:
            self._put_packed_by_sample(data, keys, ends, routes)
        pub = self._publishers.get(self._batch_key) or self._publisher(self._batch_key)
        if pub.matching_status.matching:
            self.put_remote(self._batch_key, data)
        self.published += len(keys)

    def _put_packed_by_sample(self, data: bytes, keys: list[bytes], ends: list[int],
                              routes: list[tuple[Subscription, ...]]) -> None:
        """:meth:`_put_batch_by_sample` from packed bytes: only the samples a per-sample or an
        unpacked batch handler takes are split out; a packed handler's share stays packed."""
        def sample(i: int) -> tuple[str, bytes]:
            return _sample_at(data, keys[i], ends[i - 1] if i else 0, ends[i])

        for sub, (n, mine) in self._post_samples(len(keys), routes, sample).items():
            share: Any
            if not sub.packed:
                share = [sample(i) for i in mine]
            elif len(mine) == len(keys):
                share = data
            else:
                keep = [False] * len(keys)
                for i in mine:
                    keep[i] = True
                share = select_samples(data, ends, keep)
            sub.clock.post(_deliver_batch, sub, share, order=(n, sub.index))

    def _post_samples(self, count: int, routes: list[tuple[Subscription, ...]],
                      sample: Callable[[int], tuple[str, bytes]]) -> dict[Subscription, tuple[int, list[int]]]:
        """Each sample ``sample(i)`` of a batch to its per-sample handlers, in publish order,
        as from put (split out only for them); the batch handlers' shares (their numbers,
        where the first stands), for the caller to post whole (a wall clock's thread may take
        a post at once)."""
        order = self._hub.order
        groups: dict[Subscription, tuple[int, list[int]]] = {}
        for i in range(count):
            subs = routes[i]
            if not subs:
                continue
            n = next(order)
            item = None
            for sub in subs:
                if sub.batch:
                    group = groups.get(sub)
                    if group is None:
                        group = groups[sub] = (n, [])
                    group[1].append(i)
                else:
                    if item is None:
                        item = sample(i)
                    sub.clock.post(_deliver, sub, item[0], item[1], order=(n, sub.index))
        return groups

    def _deliver_batch(self, items: Samples, routes: list[tuple[Subscription, ...]],
                       distinct: set[tuple[Subscription, ...]], data: bytes | None, ends: list[int] | None) -> None:
        """The local half of a batch: ``data`` its packed bytes (None: nobody here takes them
        packed), ``ends`` where each sample ends in them (None: not known)."""
        if all(sub.batch for subs in distinct for sub in subs):
            self._put_batch_to_batches(items, routes, distinct, data, ends)
        else:
            self._put_batch_by_sample(items, routes, data)

    def _put_batch_to_batches(self, items: Samples, routes: list[tuple[Subscription, ...]],
                              distinct: set[tuple[Subscription, ...]], data: bytes | None,
                              ends: list[int] | None) -> None:
        """Only batch handlers here (a recorder, a monitor): each gets its samples in one
        post, taken whole when it matches every key of the batch."""
        subs = sorted({sub for group in distinct for sub in group}, key=lambda s: s.index)
        if not subs:
            return
        n = next(self._hub.order)
        for sub in subs:
            whole = all(sub in group for group in distinct)
            mine: Any
            if whole:
                mine = data if sub.packed else list(items)
            elif sub.packed and ends is not None and data is not None:
                mine = select_samples(data, ends, [sub in group for group in routes])
            else:
                mine = [item for item, group in zip(items, routes) if sub in group]
                if sub.packed:
                    mine = pack_batch(mine)
            sub.clock.post(_deliver_batch, sub, mine, order=(n, sub.index))

    def _put_batch_by_sample(self, items: Samples, routes: list[tuple[Subscription, ...]],
                             data: bytes | None) -> None:
        """Per-sample handlers among them: each sample in publish order, as from put; a batch
        handler's samples in one post, where its first sample stands."""
        for sub, (n, mine) in self._post_samples(len(items), routes, items.__getitem__).items():
            share: Any = [items[i] for i in mine]
            if sub.packed:
                share = data if data is not None and len(mine) == len(items) else pack_batch(share)
            sub.clock.post(_deliver_batch, sub, share, order=(n, sub.index))

    def put_remote(self, key: str, payload: bytes) -> None:
        """Publish to other processes only (what :meth:`put` does after the local delivery;
        alone, for control traffic this process's subscribers have no use for: the lockstep
        words)."""
        pub = self._publishers.get(key) or self._publisher(key)
        hub = self._hub
        if hub.attachment is None:
            pub.put(payload)
        else:
            pub.put(payload, attachment=hub.attachment)
        hub.sent = True

    def _publisher(self, key: str) -> Any:
        pub = self._publishers.get(key)
        if pub is None:
            # blocking congestion control: a slow peer slows the run down, it loses nothing
            pub = self._publishers[key] = self.session.declare_publisher(
                key, allowed_destination=zenoh.Locality.REMOTE,
                congestion_control=zenoh.CongestionControl.BLOCK)
        return pub

    def wait_remote(self, key: str, timeout_s: float = 10.0) -> bool:
        """Wait until a subscriber in another process matches ``key`` (False after
        ``timeout_s``). zenoh routes a sample only where a subscription is already known: a
        participant that joins and publishes at once loses what it puts before then."""
        import time

        pub = self._publisher(key)
        deadline = time.monotonic() + timeout_s
        while not pub.matching_status.matching:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)  # zenoh offers no wait on a matching status from Python
        return True

    def put_json(self, key: str, obj: Any) -> None:
        self.put(key, _dumps(obj).encode())

    def next_seq(self, src: str) -> int:
        n = self._seq.get(src, 0)
        self._seq[src] = n + 1
        return n

    def publish_frame(self, frame: Frame, *, src: str, dst: str, sim_time_ns: int | None = None,
                      **extra: Any) -> Envelope:
        env = Envelope.of(frame, src=src, dst=dst,
                          sim_time_ns=self.clock.now_ns() if sim_time_ns is None else sim_time_ns,
                          wall_time_ns=self.clock.wall_ns(), seq=self.next_seq(src), **extra)
        self.put(self.keys.frame(frame.link.value, src), _envelope_json(env))
        return env

    def frame_sample(self, frame: Frame, *, src: str, dst: str, sim_time_ns: int,
                     **extra: Any) -> tuple[str, bytes]:
        """The sample :meth:`publish_frame` would put (its seq taken now), for a
        :meth:`put_batch` of many."""
        env = Envelope(frame.link.value, src, dst, frame.raw, sim_time_ns, self.clock.wall_ns(),
                       self.next_seq(src), frame.kind.value, frame.view, **extra)
        key = self._frame_keys.get((frame.link, src))
        if key is None:
            key = self._frame_keys[(frame.link, src)] = self.keys.frame(frame.link.value, src)
        return key, _envelope_json(env)

    def event(self, src: str, kind: str, **fields: Any) -> None:
        """Errors are data: publish an event (overrun, collision, timeout, fault...)."""
        self.put_json(self.keys.event(src), {"kind": kind, "src": src,
                                             "sim_time_ns": self.clock.now_ns(), **fields})

    # -- subscribing ---------------------------------------------------------------------
    def subscribe(self, keyexpr: str, handler: Handler, *, who: str | None = None) -> Subscription:
        """``handler(key, payload)`` runs on the clock thread, for samples of this process
        and of every other that reaches this one. ``who`` names the participant in the
        ``bad-sample`` events of samples from elsewhere it cannot take (default: the
        handler's owner, :func:`participant`)."""
        sub = Subscription(zenoh.KeyExpr(keyexpr), handler, self, next(self._hub.index),
                           self._hub, who or participant(handler))
        self._hub.add(sub)
        self._subs.append(sub)
        return sub

    def subscribe_batch(self, keyexpr: str, handler: BatchHandler | PackedHandler, *, who: str | None = None,
                        packed: bool = False) -> Subscription:
        """``handler(samples)``, ``samples`` a list of ``(key, payload)`` in publish order: all
        the samples of one :meth:`put_batch` or :meth:`put_packed` (here or in another process)
        that match ``keyexpr`` in one call, a sample put alone as a list of one. ``packed``:
        ``samples`` is those samples in :func:`pack_batch`'s bytes instead (a batch put packed
        and matching only this handler's keys: its bytes as they were put). Same thread and
        ``bad-sample`` rules as :meth:`subscribe`."""
        sub = Subscription(zenoh.KeyExpr(keyexpr), handler, self, next(self._hub.index),
                           self._hub, who or participant(handler), batch=True, packed=packed)
        self._hub.add(sub)
        self._subs.append(sub)
        return sub

    def subscribe_json(self, keyexpr: str, handler: Callable[[str, Any], None]) -> Any:
        """``handler(key, obj)`` with the payload decoded from JSON."""
        return self.subscribe(keyexpr, lambda k, p: handler(k, json.loads(p)), who=participant(handler))

    def subscribe_frames(self, handler: Callable[[Envelope], None], link: str | None = None, *,
                         keyexpr: str | None = None) -> Any:
        """``handler(envelope)`` for every frame (of one ``link``, or under ``keyexpr``):
        receivers get typed envelopes, as python-can's listeners get messages."""
        if keyexpr is None:
            keyexpr = self.keys.frames if link is None else self.keys.frames_of(link)
        return self.subscribe(keyexpr, lambda k, p: handler(Envelope.from_json(p)),
                              who=participant(handler))

    def on_control(self, prefix: str, fn: Callable[[str, str, bytes], None]) -> None:
        """Samples from other processes whose key starts with ``prefix`` go to
        ``fn(sender, key, payload)`` at once, on zenoh's thread, not to the clock: control
        traffic (the lockstep barrier) that must be seen while the clock waits, in arrival
        order with the samples that came before it from the same process. Needs a
        subscription of this session under ``hexbot/`` (samples arrive through it)."""
        self._hub.control.append((prefix, fn))

    def flush(self) -> None:
        """Return once every other process subscribed to this session's samples holds all
        that it put so far (at most FLUSH_TIMEOUT_S)."""
        self._hub.flush()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for sub in self._subs:
            sub.undeclare()
        hub = self._hub
        hub.users -= 1
        if hub.users <= 0:
            hub.close()
            _HUBS.pop(id(self.session), None)
        if self._own_session:
            if hub.sent:
                hub.flush()
            self.session.close()


def open_bus(args: Any, clock: Clock | None = None) -> Bus:
    """The one way a CLI opens its bus (python-can's ``create_bus_from_namespace``): from the
    options of :func:`bus.session.add_arguments` (``--fleet``, ``--connect``, ``--listen``,
    ``--mode``, ``--isolated``) and ``--clock`` (``wall`` unless the parser has one).
    A fleet name unusable in a key is a :class:`~bus.errors.UsageError`."""
    fleet = getattr(args, "fleet", None) or "default"
    try:
        check_chunk(fleet, "fleet")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if clock is None:
        clock = make_clock(getattr(args, "clock", None) or "wall")
    return Bus(clock, fleet, options=SessionOptions.from_args(args))


_dumps = json.JSONEncoder(separators=(",", ":")).encode


def _envelope_json(e: Envelope) -> bytes:
    """``Envelope.to_json()`` byte for byte (same keys, same order), without asdict's deep copies.
    A frame's bytes decode to the same kind and view every time (noise aside: its reason says
    what came around it), so their JSON is made once per (link, bytes) and kept."""
    if e.kind == "noise":
        return _dumps({"link": e.link, "src": e.src, "dst": e.dst, "raw": e.raw.hex(),
                       "sim_time_ns": e.sim_time_ns, "wall_time_ns": e.wall_time_ns, "seq": e.seq,
                       "kind": e.kind, "view": e.view, "first_byte_ns": e.first_byte_ns,
                       "origin": e.origin, "channel": e.channel, "v": SCHEMA_VERSION}).encode()
    key = (e.link, e.raw)
    parts = _FRAME_PARTS.get(key)
    if parts is None:
        if len(_FRAME_PARTS) >= _FRAME_PARTS_MAX:
            _FRAME_PARTS.clear()
        parts = _FRAME_PARTS[key] = frame_json_parts(e.link, e.raw, e.kind, e.view)
    names = _NAMES.get((e.src, e.dst, e.origin, e.channel))
    if names is None:
        names = _NAMES[(e.src, e.dst, e.origin, e.channel)] = frame_json_names(e.src, e.dst, e.origin, e.channel)
    first = "null" if e.first_byte_ns is None else e.first_byte_ns
    return (f'{parts[0]}{names[0]}{parts[1]}{e.sim_time_ns},"wall_time_ns":{e.wall_time_ns},'
            f'"seq":{e.seq}{parts[2]}{first}{names[1]}').encode()


def frame_json_parts(link: str, raw: bytes, kind: str, view: Any) -> tuple[str, str, str]:
    """An envelope's JSON (``Envelope.to_json``'s bytes) is ``p0 names0 p1 <sim_time_ns>
    ,"wall_time_ns":<wall> ,"seq":<seq> p2 <first_byte_ns> names1``: ``p0, p1, p2`` of a
    frame's link, bytes, kind and view (here), ``names0, names1`` of its endpoints
    (:func:`frame_json_names`). The fleet core renders its frames from these parts."""
    return ('{"link":' + _dumps(link) + ',"src":', ',"raw":"' + raw.hex() + '","sim_time_ns":',
            ',"kind":' + _dumps(kind) + ',"view":' + _dumps(view) + ',"first_byte_ns":')


def frame_json_names(src: str, dst: str, origin: str, channel: int | None) -> tuple[str, str]:
    """``names0, names1`` of :func:`frame_json_parts` (``names1`` ends the envelope)."""
    return (_dumps(src) + ',"dst":' + _dumps(dst),
            ',"origin":' + _dumps(origin) + ',"channel":' + ("null" if channel is None else str(channel))
            + f',"v":{SCHEMA_VERSION}}}')


#: the JSON of each frame's fixed parts, by (link, bytes); bounded (a fuzz run makes millions)
_FRAME_PARTS: dict[tuple[str, bytes], tuple[str, str, str]] = {}
_FRAME_PARTS_MAX = 1 << 16
_NAMES: dict[tuple[str, str, str, int | None], tuple[str, str]] = {}
