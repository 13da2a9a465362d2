"""Argument types shared by the subcommands: bad values are refused by argparse in one line."""

from __future__ import annotations

import argparse


def baud(text: str) -> int:
    """A baud rate: a whole number from 1 to 1 000 000."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of baud") from None
    if not 1 <= value <= 1_000_000:
        raise argparse.ArgumentTypeError(f"{value} baud: expected 1..1000000 (IR: 300, UARTs: 4800)")
    return value
