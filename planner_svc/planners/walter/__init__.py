"""Walter, Tsai & Amato's distributed reconfiguration: the PC's half (section 4) and the
round model of the modules' half (section 5). See docs/planner.md ("Walter").

* :func:`choose` -- the substrate path, its cost, I, the rounds predicted; or
  :class:`Inadmissible` with the reason.
* :class:`RoundModel` -- Figure 10 for every module, round by round: the reference the
  fleet is held to.
"""

from .choose import Candidate, Choice, Inadmissible, candidates, check_chain, choose
from .graph import build_h, path_cost, path_violation, traverse_graph, vertex_weights
from .rounds import DELAYS, ModuleState, Round, RoundModel, RoundMove, Schedule

__all__ = ["Candidate", "Choice", "Inadmissible", "candidates", "check_chain", "choose",
           "build_h", "path_cost", "path_violation", "traverse_graph", "vertex_weights",
           "DELAYS", "ModuleState", "Round", "RoundModel", "RoundMove", "Schedule"]
