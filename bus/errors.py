"""One error family (python-can's ``CanError`` way): callers catch :class:`HexbenchError`.

A CLI prints any of them as one line, ``hexbench <command>: error: ...``, never a traceback.
"""

from __future__ import annotations


class HexbenchError(Exception):
    """The base of every error hexbench raises on purpose; the message says what is wrong."""


class UsageError(HexbenchError):
    """Bad input on the command line: printed as ``hexbench <command>: error: ...``, exit 2."""
