"""hexbench recordings."""
