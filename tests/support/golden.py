"""The golden frames of thesis-12 (``hexbench run thesis-12 --planner complete --clock
virtual``, either program): the recording tests and the install test hold a run to them."""

from __future__ import annotations

#: thesis-12's frames alone, in sim-time order (ties by topic and seq): what a fleet core that
#: no longer publishes light between modules as samples, or writes a window's samples in another
#: file order, must still give. The all-samples digest (test_determinism) changes with either;
#: this one only with the frames themselves (last re-made: the O(n + d) bring-up, 155 frames
#: fewer: no Report of every module before Ref and none after every Localize step).
GOLDEN_THESIS_12_FRAMES = (1967, "4983606bbce0d61c83ee4a6f8774a577feae28fd71ae606ab184038a187bfd59")

#: walter-4 by ``--planner walter`` on the virtual clock (bring-up, upload, ten rounds, 12 moves
#: the modules decide and make themselves): the same frames with the Python programs and the C
#: firmware. Made with the Walter run (issue 49); a change of Walter's codes, the side-link
#: exchange, the beat or the bring-up changes it on purpose.
GOLDEN_WALTER_4_FRAMES = (762, "3d83e202f8361ae0a7348590a4a2e27728f80ca7664a079e7818f21bd8ab9168")


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
