"""Virtual HexBot modules (both AVR programs) and the world they live in."""

from .comm_board import CommBoard
from .control_board import ControlBoard
from .fleet import Fleet
from .module import VirtualModule
from .profiles import PROFILES, THESIS_2009, V2, Profile
from .world import World

__all__ = ["CommBoard", "ControlBoard", "Fleet", "PROFILES", "Profile", "THESIS_2009", "V2",
           "VirtualModule", "World"]
