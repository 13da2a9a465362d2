"""``--live rerun[=URL]`` and ``--live foxglove[=HOST:PORT]``: watch a run while it goes.

* ``rerun``: the replay's entities streamed to a rerun viewer (:mod:`recordings.live_rerun`);
  a viewer is spawned, or with ``=URL`` (``rerun+http://127.0.0.1:9876/proxy``) the stream goes
  to one that is already running.
* ``foxglove``: a Foxglove WebSocket server (:mod:`recordings.live_foxglove`), on
  ``127.0.0.1:8765`` unless ``=HOST:PORT`` says otherwise; open it in the Foxglove app.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any, Callable

from bus import UsageError

KINDS = ("rerun", "foxglove")


@dataclass(frozen=True)
class LiveSpec:
    kind: str  # "rerun" or "foxglove"
    address: str | None = None  # rerun: a gRPC URL; foxglove: HOST:PORT


def live_spec(text: str) -> LiveSpec:
    """``rerun``, ``rerun=URL``, ``foxglove`` or ``foxglove=HOST:PORT`` (argparse type)."""
    kind, _, address = text.partition("=")
    if kind not in KINDS:
        raise argparse.ArgumentTypeError(f"--live {text!r}: expected rerun[=URL] or foxglove[=HOST:PORT]")
    if kind == "foxglove" and address:
        host, _, port = address.rpartition(":")
        if not host or not port.isdigit() or not 0 <= int(port) < 65536:
            raise argparse.ArgumentTypeError(f"--live {text!r}: expected foxglove=HOST:PORT, e.g. foxglove=127.0.0.1:8765")
    return LiveSpec(kind, address or None)


def add_live_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--live", action="append", default=[], type=live_spec, metavar="VIEWER",
                   help="watch it live: 'rerun' (spawn a viewer), 'rerun=URL' (stream to a running "
                        "viewer, e.g. rerun+http://127.0.0.1:9876/proxy), 'foxglove' (serve a "
                        "Foxglove WebSocket on 127.0.0.1:8765) or 'foxglove=HOST:PORT'; repeatable")


def start_live(specs: list[LiveSpec], bus: Any, *, meta: dict[str, Any] | None = None,
               say: Callable[[str], None] = print) -> list[Callable[[], None]]:
    """Attach a live view per spec to ``bus``; returns what closes them (call in a finally)."""
    closers: list[Callable[[], None]] = []
    try:
        for spec in specs:
            if spec.kind == "foxglove":
                from recordings.live_foxglove import DEFAULT_HOST, DEFAULT_PORT, LiveFoxglove
                host, port = DEFAULT_HOST, DEFAULT_PORT
                if spec.address:
                    host, _, p = spec.address.rpartition(":")
                    port = int(p)
                try:
                    fox = LiveFoxglove(fleet=bus.keys.fleet, host=host, port=port)
                except RuntimeError as exc:  # the SDK's "address in use" and the like
                    raise UsageError(f"--live foxglove: cannot serve on {host}:{port}: {exc}") from None
                fox.attach(bus)
                closers.append(fox.close)
                say(f"live: Foxglove WebSocket on {fox.url} (Foxglove: Open connection -> Foxglove WebSocket)")
            else:
                from recordings.live_rerun import LiveRerun, open_stream
                stream = open_stream(connect=spec.address, spawn=spec.address is None)
                live = LiveRerun(stream, fleet=bus.keys.fleet, meta=meta)
                live.attach(bus)

                def close_rerun(live: Any = live, stream: Any = stream) -> None:
                    live.close()  # draws what it still holds; the stream is ours to end
                    stream.disconnect()
                closers.append(close_rerun)
                say(f"live: rerun {'viewer spawned' if spec.address is None else 'stream to ' + spec.address}")
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    return closers
