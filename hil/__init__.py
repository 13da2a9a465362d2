"""hexbench hil."""
