"""``hexbench``: one CLI, a thin shell over the packages.

Each package contributes its subcommands through a ``register(subparsers)``
function in its ``cli`` module; heavy imports happen only when a subcommand runs.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

#: Packages whose ``cli.register`` adds subcommands, in help order.
PACKAGES = ("bus.tools", "module_sim.cli", "planner_svc.cli", "recordings.cli", "hil.cli")


class UsageError(Exception):
    """Bad input on the command line: printed as ``hexbench: error: ...``, exit 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hexbench",
        description="HexBot hardware-in-the-loop testbench: virtual modules, planner, "
                    "serial bridges, MCAP recordings and rerun replays on a zenoh bus.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in PACKAGES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and name.startswith(exc.name):
                continue  # that package has no CLI yet
            raise
        mod.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"hexbench {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `hexbench plan ... | head`: the reader left, not an error
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
