"""``python -m planner_svc <scenario> --planner <name> --clock wall``: see planner_svc.run."""

import sys

from .run import main

sys.exit(main())
