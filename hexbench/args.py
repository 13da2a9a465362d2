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


def instant(text: str) -> int:
    """An ISO 8601 instant (``2026-11-25T08:00:00Z``; no zone: UTC) as ns since the epoch."""
    from datetime import datetime, timezone
    try:
        dt = datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an ISO 8601 instant (e.g. 2026-11-25T08:00:00Z)") from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    return int(dt.timestamp()) * 1_000_000_000 + dt.microsecond * 1000
