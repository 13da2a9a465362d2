"""Bus.put_batch: what put does for each sample, in order, here and in other processes (one
zenoh sample a batch, unpacked there); batch handlers get a batch's samples in one call.
Bus.put_packed: the same from the packed bytes, unpacked only for handlers that take samples."""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from typing import Iterator

import pytest

from bus import SessionOptions, VirtualClock, WallClock
from bus.lockstep import LockstepClock
from bus import transport
from bus.transport import BATCH_PREFIX, Bus, batch_keys, pack_batch, select_samples, unpack_batch
from processes import free_port


def _items(fleet: str, n: int) -> list[tuple[str, bytes]]:
    keys = [f"hexbot/{fleet}/frame/side/m{i % 5}.comm" for i in range(n)]
    keys[3] = f"hexbot/{fleet}/world/event"
    return [(k, b'{"i":%d}' % i) for i, k in enumerate(keys)]


def test_pack_and_unpack_are_inverse_and_refuse_bad_bytes():
    items = [("hexbot/f/a", b""), ("hexbot/f/\u00e9", b"x" * 70_000), ("k", b"\x00\x01")]
    data = pack_batch(items)
    assert data[:6] == b"\x0a\x00\x00\x00\x00\x00" and unpack_batch(data) == items
    assert unpack_batch(b"") == []
    for bad in (data[:-1], data[:5], b"\x00\x00\x01\x00\x00\x00x", b"\x02\x00\x00\x00\x00\x00\xff\xfe"):
        with pytest.raises(ValueError):
            unpack_batch(bad)


def _put(bus: Bus, how: str, items: list[tuple[str, bytes]]) -> None:
    """``put_batch(items)``, or the same batch packed first and put with ``put_packed``."""
    if how == "batch":
        bus.put_batch(items)
    else:
        bus.put_packed(pack_batch(items))


def test_batch_keys_and_select_samples_read_the_packed_bytes():
    items = _items("sel", 9)
    data = pack_batch(items)
    keys, ends = batch_keys(data)
    assert [k.decode() for k in keys] == [k for k, _ in items] and ends[-1] == len(data)
    keep = [i % 3 != 1 for i in range(9)]
    assert unpack_batch(select_samples(data, ends, keep)) == [it for it, k in zip(items, keep) if k]
    assert select_samples(data, ends, [False] * 9) == b"" and select_samples(data, ends, [True] * 9) == data
    for bad in (data[:-1], data[:5]):
        with pytest.raises(ValueError):
            batch_keys(bad)


def _handlers(bus: Bus, log: list) -> None:
    """Every kind of subscriber, each logging what it gets into one list (so the order across
    handlers counts too)."""
    bus.subscribe(bus.keys.all, lambda k, p: log.append(("sample", k, p)))
    bus.subscribe_batch(bus.keys.all, lambda items: log.append(("batch", list(items))))
    bus.subscribe(bus.keys.frames, lambda k, p: log.append(("frame", k, p)))
    bus.subscribe_batch(bus.keys.all, lambda data: log.append(("packed", unpack_batch(data))), packed=True)
    bus.subscribe_batch(f"{bus.keys.root}/world/**", lambda data: log.append(("world", unpack_batch(data))),
                        packed=True)


def test_put_packed_does_what_put_batch_does_for_every_handler():
    logs = {}
    for how in ("batch", "packed"):
        clock = VirtualClock()
        bus = Bus(clock, "packed-local", options=SessionOptions(isolated=True))
        try:
            log: list = []
            _handlers(bus, log)
            items = _items("packed-local", 40)
            _put(bus, how, items)
            bus.put(items[0][0], b"alone")
            _put(bus, how, [("hexbot/other/x", b"nobody")])
            clock.run()
            logs[how] = log
            assert bus.published == 42
        finally:
            bus.close()
    assert logs["packed"] == logs["batch"]
    log = logs["packed"]
    assert [e[1:] for e in log if e[0] == "sample"][:40] == _items("packed-local", 40)
    assert [e for e in log if e[0] == "world"] == [("world", [_items("packed-local", 40)[3]])]


def _refuse_unpacking(monkeypatch) -> None:
    def refuse(data):
        raise AssertionError("a batch unpacked whole")

    monkeypatch.setattr(transport, "unpack_batch", refuse)


def test_packed_handlers_alone_get_the_bytes_as_they_were_put(monkeypatch):
    _refuse_unpacking(monkeypatch)
    clock = VirtualClock()
    bus = Bus(clock, "packed-only", options=SessionOptions(isolated=True))
    try:
        whole: list[bytes] = []
        world: list[bytes] = []
        bus.subscribe_batch(bus.keys.all, whole.append, packed=True)
        bus.subscribe_batch(f"{bus.keys.root}/world/**", world.append, packed=True)
        items = _items("packed-only", 30)
        data = pack_batch(items)
        bus.put_packed(data)
        clock.run()
        assert whole == [data] and whole[0] is data
        assert world == [pack_batch([items[3]])]
        with pytest.raises(ValueError):
            bus.put_packed(data[:-1])
        assert bus.published == 30
    finally:
        bus.close()


def test_put_packed_splits_out_only_the_samples_a_sample_handler_takes(monkeypatch):
    _refuse_unpacking(monkeypatch)
    clock = VirtualClock()
    bus = Bus(clock, "packed-some", options=SessionOptions(isolated=True))
    try:
        log: list = []
        bus.subscribe_batch(bus.keys.all, lambda data: log.append(("packed", data)), packed=True)
        bus.subscribe(f"{bus.keys.root}/world/**", lambda k, p: log.append(("world", k, p)))
        items = _items("packed-some", 30)
        data = pack_batch(items)
        bus.put_packed(data)
        clock.run()
        assert log == [("packed", data), ("world", *items[3])]  # each where its first sample stands
    finally:
        bus.close()


def test_in_process_every_handler_sees_every_sample_in_order():
    clock = VirtualClock()
    bus = Bus(clock, "batch-local", options=SessionOptions(isolated=True))
    try:
        singles: list[tuple[str, bytes]] = []
        calls: list[list[tuple[str, bytes]]] = []
        frames: list[str] = []
        bus.subscribe(bus.keys.all, lambda k, p: singles.append((k, p)))
        bus.subscribe_batch(bus.keys.all, calls.append)
        bus.subscribe(bus.keys.frames, lambda k, p: frames.append(k))
        items = _items("batch-local", 40)
        bus.put_batch(items)
        bus.put(items[0][0], b"alone")
        bus.put_batch([])
        bus.put_batch([("hexbot/other/x", b"nobody")])
        clock.run()
        assert singles == items + [(items[0][0], b"alone")]
        assert calls == [items, [(items[0][0], b"alone")]]  # one call a batch, a put a list of one
        assert frames == [k for k, _ in items if "/frame/" in k] + [items[0][0]]
        assert bus.published == 42
    finally:
        bus.close()


@contextmanager
def _pair(fleet: str, clock_b) -> Iterator[tuple[Bus, Bus]]:
    """Bus ``a`` (listening) and bus ``b`` on ``clock_b`` (connected): two zenoh sessions, as two
    processes have."""
    port = free_port()
    a = Bus(WallClock(), fleet, options=SessionOptions(listen=[f"tcp/127.0.0.1:{port}"]))
    b = Bus(clock_b, fleet, options=SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        yield a, b
    finally:
        a.close()
        b.close()


def _wait_route(a: Bus) -> None:
    """Once ``b``'s subscriptions are made: ``a``'s batches reach it."""
    assert a.wait_remote(f"{BATCH_PREFIX}/{a.keys.fleet}", timeout_s=15), "the batch never found its subscriber"


@pytest.mark.parametrize("how", ["batch", "packed"])
def test_another_process_gets_every_sample_under_its_own_key_in_order(how):
    fleet = f"batch{how}{os.getpid()}"
    clock = WallClock()
    with _pair(fleet, clock) as (a, b):
        singles: list[tuple[str, bytes]] = []
        batched: list[tuple[str, bytes]] = []
        calls = []
        control: list[tuple[str, str, bytes]] = []
        b.subscribe(b.keys.all, lambda k, p: singles.append((k, p)))
        b.subscribe_batch(b.keys.all, lambda items: (calls.append(len(items)), batched.extend(items)))
        packed: list[tuple[str, bytes]] = []
        b.subscribe_batch(b.keys.all, lambda data: packed.extend(unpack_batch(data)), packed=True)
        b.on_control(f"hexbot/{fleet}/ctl/", lambda s, k, p: control.append((s, k, p)))
        _wait_route(a)
        a.sender = "alpha"
        items = _items(fleet, 500)
        ctl = (f"hexbot/{fleet}/ctl/word", b"go")
        _put(a, how, items[:250] + [ctl] + items[250:])
        _put(a, how, items[:3])
        clock.run(until=lambda: len(singles) >= 503 and len(batched) >= 503 and len(packed) >= 503, timeout_s=20)
        assert singles == items + items[:3]
        assert batched == items + items[:3]
        assert packed == items + items[:3]
        assert calls == [250, 250, 3]  # the control word splits the first batch where it stood
        assert control == [("alpha", *ctl)]


def test_another_process_hands_a_packed_handler_the_bytes_as_they_were_put(monkeypatch):
    fleet = f"batchpk{os.getpid()}"
    clock = WallClock()
    with _pair(fleet, clock) as (a, b):
        got: list[bytes] = []
        world: list[bytes] = []
        b.subscribe_batch(b.keys.all, got.append, packed=True)
        b.subscribe_batch(f"{b.keys.root}/world/**", world.append, packed=True)
        _wait_route(a)
        _refuse_unpacking(monkeypatch)
        items = _items(fleet, 50)
        data = pack_batch(items)
        a.put_packed(data)
        clock.run(until=lambda: got and world, timeout_s=20)
        assert got == [data] and world == [pack_batch([items[3]])]


@pytest.mark.parametrize("how", ["batch", "packed"])
def test_a_lockstep_receiver_holds_a_batch_by_sender_in_order(how):
    fleet = f"batchls{how}{os.getpid()}"
    clock = LockstepClock()
    with _pair(fleet, clock) as (a, b):
        got: list[str] = []
        b.subscribe(b.keys.all, lambda k, p: got.append(p.decode()))
        b.subscribe_batch(b.keys.all, lambda items: got.append(f"batch of {len(items)}"))
        _wait_route(a)
        a.sender = "shard-a"
        items = _items(fleet, 20)
        _put(a, how, items)
        deadline = time.monotonic() + 20
        while len(clock._held.get("shard-a", [])) < 21:  # noqa: SLF001  (held, not handled)
            assert time.monotonic() < deadline, clock._held
            time.sleep(0.01)
        assert got == []
        clock.release(1_000_000)
        assert got == [p.decode() for _, p in items] + ["batch of 20"]


def test_a_malformed_batch_from_elsewhere_is_a_bad_sample_event():
    fleet = f"batchbad{os.getpid()}"
    clock = WallClock()
    with _pair(fleet, clock) as (a, b):
        events: list[dict] = []
        got: list[str] = []
        b.subscribe_json(f"{b.keys.root}/event/*", lambda k, d: events.append(d))
        b.subscribe(b.keys.frames, lambda k, p: got.append(k))
        _wait_route(a)
        a.put_remote(f"{BATCH_PREFIX}/{fleet}", b"\x05\x00\x10\x00\x00\x00hexbot/cut")
        a.put_batch(_items(fleet, 5))  # and the next batch still arrives
        clock.run(until=lambda: events and len(got) >= 4, timeout_s=20)
        assert events[0]["kind"] == "bad-sample" and events[0]["src"] == "bus"
        assert events[0]["key"] == f"{BATCH_PREFIX}/{fleet}" and "ValueError" in events[0]["reason"]
        assert len(got) == 4
