"""hexbench's bus: the one shared contract, and the ``Bus`` itself.

The wire codec and framers, the function table (Table 3-7), the pin maps
(Tables 3-3..3-5), the lattice (Table 4-1, Table 4-3), the frame envelope and
key expressions, the zenoh session, the two clocks and scenario files.

A script needs only these names (python-can's way: one import)::

    from bus import Bus, Envelope, WallClock, open_bus

    bus = Bus(WallClock(), "default")
    bus.subscribe_frames(lambda env: print(env.link, env.frame.describe()))
    bus.clock.run(timeout_s=10)
"""

from .clock import Clock, ClockError, VirtualClock, WallClock, make_clock
from .codec import Frame, Kind, Link, encode_command, parse
from .envelope import Envelope
from .errors import HexbenchError, UsageError
from .framer import Framer
from .functions import FUNCTIONS, Board, FunctionCode, lookup
from .keys import Keys
from .lattice import Cell, Direction, Joint, MOVE_RULES, Side
from .scenario import Scenario, ScenarioError, load as load_scenario
from .session import SessionOptions, add_arguments as add_bus_arguments
from .transport import Bus, open_bus

__all__ = [
    "Board", "Bus", "Cell", "Clock", "ClockError", "Direction", "Envelope", "FUNCTIONS", "Frame",
    "Framer", "FunctionCode", "HexbenchError", "Joint", "Keys", "Kind", "Link", "MOVE_RULES",
    "Scenario", "ScenarioError", "SessionOptions", "Side", "UsageError", "VirtualClock",
    "WallClock", "add_bus_arguments", "encode_command", "load_scenario", "lookup", "make_clock",
    "open_bus", "parse",
]
