"""hexbench's bus: the one shared contract.

The wire codec and framers, the function table (Table 3-7), the pin maps
(Tables 3-3..3-5), the lattice (Table 4-1, Table 4-3), the frame envelope and
key expressions, the zenoh session, the two clocks and scenario files.
"""

from .clock import Clock, VirtualClock, WallClock, make_clock
from .codec import Frame, Kind, Link, encode_command, parse
from .envelope import Envelope
from .framer import Framer
from .functions import FUNCTIONS, Board, FunctionCode, lookup
from .keys import Keys
from .lattice import Cell, Direction, Joint, MOVE_RULES, Side
from .scenario import Scenario, ScenarioError, load as load_scenario

__all__ = [
    "Board", "Cell", "Clock", "Direction", "Envelope", "FUNCTIONS", "Frame", "Framer",
    "FunctionCode", "Joint", "Keys", "Kind", "Link", "MOVE_RULES", "Scenario", "ScenarioError",
    "Side", "VirtualClock", "WallClock", "encode_command", "load_scenario", "lookup", "make_clock",
    "parse",
]
