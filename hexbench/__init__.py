"""hexbench, the application: the one layer that composes the packages below it.

``bus`` is the contract; ``module_sim``, ``hil``, ``recordings`` and ``planner_svc`` each build
on it alone. Here they meet: the CLI (:mod:`hexbench.cli`), a whole run (:mod:`hexbench.run`),
a fleet on its own (:mod:`hexbench.fleet`), the demo, the hardware stand-in, replays compared
against a fresh virtual run, and the pytest plugin with its conformance suite.
"""
