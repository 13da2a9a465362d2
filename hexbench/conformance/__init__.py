"""The wire-protocol conformance suite (spec §5-§9), runnable against any target:
``pytest --pyargs hexbench.conformance --hexbench-target virtual``."""
