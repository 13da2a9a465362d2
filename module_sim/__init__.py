"""hexbench module_sim."""
