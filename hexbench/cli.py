"""``hexbench``: one CLI, a thin shell over the packages.

Each module of this package named in :data:`COMMANDS` adds its subcommands through a
``register(subparsers)`` function; heavy imports happen only when a subcommand runs.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from bus.errors import HexbenchError, UsageError

from . import boards, firmware, fleet, hil, plan, programmer, record, tools

#: Modules whose ``register`` adds subcommands, in help order.
COMMANDS = (tools, fleet, plan, record, hil, boards, firmware, programmer)


def _version() -> str:
    """The installed distribution's version (pyproject.toml)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("hexbench")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hexbench",
        description="HexBot hardware-in-the-loop testbench: virtual modules, planner, "
                    "serial bridges, MCAP recordings and rerun replays on a zenoh bus.")
    parser.add_argument("--version", action="version", version=f"hexbench {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in COMMANDS:
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
    except HexbenchError as exc:  # anything else said on purpose: one line, no traceback
        print(f"hexbench {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `hexbench plan ... | head`: the reader left, not an error
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
