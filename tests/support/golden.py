"""The golden frames of thesis-12 (``hexbench run thesis-12 --planner complete --clock
virtual``, either program): the recording tests and the install test hold a run to them."""

from __future__ import annotations

#: thesis-12's frames alone, in sim-time order (ties by topic and seq): what a fleet core that
#: no longer publishes light between modules as samples, or writes a window's samples in another
#: file order, must still give. The all-samples digest (test_determinism) changes with either;
#: this one only with the frames themselves.
GOLDEN_THESIS_12_FRAMES = (2122, "a9af899fc0a04768ca0782cb74986fd5b38992c2c9e6de59cc577101c036fb97")


def frames_digest(path) -> tuple[int, str]:
    import hashlib
    import json

    from mcap.reader import make_reader

    rows = []
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if channel.message_encoding == "json" and channel.topic.startswith("frame/"):
                d = json.loads(message.data)
                rows.append((d["sim_time_ns"], channel.topic, d["seq"], d["link"], d["src"], d["dst"],
                             d.get("channel"), d["kind"], d.get("first_byte_ns"), d["raw"]))
    rows.sort()
    return len(rows), hashlib.sha256(repr(rows).encode()).hexdigest()
