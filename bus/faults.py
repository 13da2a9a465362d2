"""Actuator faults the world can inject: a relay or a solenoid that does not do its job.

One spec format for scenario files (``faults = ["m3.S2-:off"]``), the command line
(``hexbench run --fault m3.S2-:off``) and the bus (``world/inject``):

=================  ==========================================================
``m3.S2:off``      both relays of side magnet S2 stuck off: S2 never energises
``m3.S2-:off``     the negative relay of S2 stuck off (S2 can still go positive)
``m3.S2+:off``     the positive relay of S2 stuck off
``m3.J4:closed``   solenoid J4 stuck: joint 4 never opens
=================  ==========================================================

Sides and joints are in the module's body frame (the pins of Tables 3-3, 3-4). The
firmware still drives its port bits (they are what the boards do); the world applies
the fault to what the actuators physically do.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Sequence

from .errors import HexbenchError

_SPEC = re.compile(r"^m(?P<id>\d{1,3})\.(?:(?P<side>S[1-6])(?P<relay>[+-]?):off|(?P<joint>J[1-6]):closed)$")


class FaultSpecError(HexbenchError, ValueError):
    """A fault spec that does not parse; the message shows the accepted forms."""


@dataclass(frozen=True)
class ActuatorFault:
    module: str  # endpoint, "m3"
    part: str  # "magnet" or "joint"
    index: int  # body side (magnet) or body joint 1..6
    relay: str = ""  # "+", "-" or "" (both) for magnets

    @classmethod
    def parse(cls, spec: str) -> "ActuatorFault":
        m = _SPEC.match(spec.strip())
        if not m:
            raise FaultSpecError(
                f"fault {spec!r} not understood; expected m<id>.S<1-6>[+|-]:off (magnet relay "
                "stuck off) or m<id>.J<1-6>:closed (solenoid stuck), e.g. m3.S2-:off")
        module = f"m{int(m['id'])}"
        if m["side"]:
            return cls(module, "magnet", int(m["side"][1]), m["relay"])
        return cls(module, "joint", int(m["joint"][1]))

    def __str__(self) -> str:
        if self.part == "magnet":
            return f"{self.module}.S{self.index}{self.relay}:off"
        return f"{self.module}.J{self.index}:closed"

    def describe(self) -> str:
        if self.part == "joint":
            return f"{self.module}: solenoid J{self.index} stuck closed"
        which = {"+": "positive relay", "-": "negative relay", "": "both relays"}[self.relay]
        return f"{self.module}: {which} of magnet S{self.index} stuck off"

    def apply(self, joints_open: Sequence[bool], magnets: Sequence[int]
              ) -> tuple[list[bool], list[int]]:
        """What the actuators do when the port bits ask for ``joints_open``/``magnets``
        (magnet values: +1, -1, 0, 2 = both relays on)."""
        joints, mags = list(joints_open), list(magnets)
        k = self.index - 1
        if self.part == "joint":
            joints[k] = False
            return joints, mags
        pos = mags[k] in (1, 2) and self.relay not in ("+", "")
        neg = mags[k] in (-1, 2) and self.relay not in ("-", "")
        mags[k] = 2 if pos and neg else 1 if pos else -1 if neg else 0
        return joints, mags


def apply_all(faults: Sequence[ActuatorFault], joints_open: Sequence[bool],
              magnets: Sequence[int]) -> tuple[list[bool], list[int]]:
    j, m = list(joints_open), list(magnets)
    for f in faults:
        j, m = f.apply(j, m)
    return j, m
