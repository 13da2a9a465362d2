"""Profiles (ARCHITECTURE principle 6): which firmware behaviour a virtual module shows.

``thesis-2009`` reproduces Appendix A's observable behaviour, defects included;
``v2`` (default) is our protocol: fleet addressing, location report, general
localization, defects fixed. docs/protocol.md lists every difference.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Profile:
    name: str
    #: SCCW energises S(i-5) negative (the firmware) instead of positive (its comment).
    sccw_both_negative: bool
    #: The comm board sets Yref = 1 at boot without localizing.
    boot_assumes_yref: bool
    #: Localize() serves only sides 2 and 3 with the fixed coordinates (0,1) and (1,0),
    #: and the receiver takes X from the tens digit and Y from the units digit.
    fixed_side_localize: bool
    #: Select, Report, Move (codes 60..62) and the id byte after the 'L' handshake.
    addressing: bool
    #: The control board reports its solenoid and magnet bits on the debug UART (``ACT``).
    actuator_report: bool = False
    #: Both boards read a frame's closing '#' and drop a frame cut by a silence
    #: (``FRAME_BYTE_TICKS``); the comm board takes only the echo of the code it relayed.
    checked_frames: bool = False


THESIS_2009 = Profile("thesis-2009", sccw_both_negative=True, boot_assumes_yref=True,
                      fixed_side_localize=True, addressing=False)
V2 = Profile("v2", sccw_both_negative=False, boot_assumes_yref=False,
             fixed_side_localize=False, addressing=True, actuator_report=True,
             checked_frames=True)
PROFILES = {p.name: p for p in (THESIS_2009, V2)}


def profile(name: str) -> Profile:
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown profile {name!r}: expected one of {', '.join(PROFILES)}") from None
