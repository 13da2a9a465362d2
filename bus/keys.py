"""The key-expression scheme: everything of a fleet lives under ``hexbot/<fleet>/``.

=========================================  ==========================================
key                                        payload (JSON, docs/bus.md)
=========================================  ==========================================
``frame/<link>/<src>``                     :class:`bus.envelope.Envelope` of a frame
``ir/tx/<src>``                            one IR byte leaving a transceiver (light on)
``ir/rx/<dst>``                            one IR byte reaching a transceiver
``world/pose/<module>``                    a module's cell and orientation
``world/actuators/<module>``               magnet/joint/LED port bits of a module
``world/event``                            move started/completed/refused, faults
``world/energy``                           energy per move and per run
``world/switches/<module>``                a module's optical switches (body frame)
``world/inject``                           inject an actuator fault (:mod:`bus.faults`)
``world/sync``                             ask the world to republish poses and switches
``world/confirm``                          a real module's confirmed pose (from the planner)
``planner/<topic>``                        planner decisions and progress
``event/<src>``                            errors as data: overrun, collision, timeout
``clock``                                  virtual time announcements
``meta``                                   run metadata (scenario, profile, seed, ...)
=========================================  ==========================================
"""

from __future__ import annotations

import re

ROOT = "hexbot"
_CHUNK = re.compile(r"^[A-Za-z0-9_.:+=-]+$")


def check_chunk(name: str, what: str = "name") -> str:
    """A key chunk must be non-empty and free of ``/ * $ ? #``."""
    if not _CHUNK.match(name):
        raise ValueError(f"{what} {name!r} is not usable in a key expression "
                         "(letters, digits and _ . : + = - only)")
    return name


def module_endpoint(module_id: int) -> str:
    return f"m{module_id}"


def board_endpoint(module_id: int, board: str) -> str:
    """``m3.comm`` / ``m3.ctrl``."""
    return f"m{module_id}.{board}"


PC = "pc"
WORLD = "world"


class Keys:
    """Key expressions of one fleet."""

    def __init__(self, fleet: str) -> None:
        self.fleet = check_chunk(fleet, "fleet")
        self.root = f"{ROOT}/{fleet}"
        self.all = f"{self.root}/**"
        self.frames = f"{self.root}/frame/**"
        self.world_event = f"{self.root}/world/event"
        self.world_energy = f"{self.root}/world/energy"
        self.world_inject = f"{self.root}/world/inject"
        self.world_sync = f"{self.root}/world/sync"
        self.world_confirm = f"{self.root}/world/confirm"
        self.poses = f"{self.root}/world/pose/*"
        self.actuators_all = f"{self.root}/world/actuators/*"
        self.clock = f"{self.root}/clock"
        self.meta = f"{self.root}/meta"
        self.ir_tx_all = f"{self.root}/ir/tx/*"
        self.ir_rx_all = f"{self.root}/ir/rx/*"

    def frame(self, link: str, src: str) -> str:
        return f"{self.root}/frame/{link}/{check_chunk(src, 'source')}"

    def frames_of(self, link: str) -> str:
        return f"{self.root}/frame/{link}/*"

    def ir_tx(self, src: str) -> str:
        return f"{self.root}/ir/tx/{check_chunk(src, 'source')}"

    def ir_rx(self, dst: str) -> str:
        return f"{self.root}/ir/rx/{check_chunk(dst, 'destination')}"

    def pose(self, module: str) -> str:
        return f"{self.root}/world/pose/{module}"

    def actuators(self, module: str) -> str:
        return f"{self.root}/world/actuators/{module}"

    def switches(self, module: str) -> str:
        return f"{self.root}/world/switches/{module}"

    def planner(self, topic: str) -> str:
        return f"{self.root}/planner/{check_chunk(topic, 'topic')}"

    def event(self, src: str) -> str:
        return f"{self.root}/event/{check_chunk(src, 'source')}"

    def relative(self, key: str) -> str:
        """``hexbot/f/frame/pc/pc`` -> ``frame/pc/pc``."""
        return key[len(self.root) + 1:] if key.startswith(self.root + "/") else key
