"""hexbench planner_svc."""
