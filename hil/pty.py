"""A pseudo-terminal to stand in for a serial cable (POSIX).

:class:`Pty` is the *device* end: it holds the pty master and offers the small part of
pyserial's API a line user needs (``read``/``write``/``in_waiting``/``close``), while a
bridge opens the other end, :attr:`Pty.path`, with pyserial like any serial port. The
slave is put in raw mode at once (no echo, no line editing), and kept open so that bytes
written before anybody listens are simply discarded when pyserial opens the port (it
flushes its input), as on a real line.

``link`` names a symlink kept pointing at the current slave, so that :meth:`hangup`
followed by :meth:`reopen` (a cable pulled and plugged back in, a new ``/dev/pts/N``)
is found again under the same name.
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import struct
import termios
import threading
import tty
from pathlib import Path


class PtyClosed(OSError):
    """The pty was closed for good."""


class Pty:
    """Master end of a pseudo-terminal, with a stable name (``link``) for the slave end."""

    def __init__(self, link: str | os.PathLike[str] | None = None, *, timeout: float = 0.05) -> None:
        self.link = Path(link) if link is not None else None
        self.timeout = timeout
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self.slave_path = ""
        self.closed = False
        self.dropped = 0  # bytes written while nobody could take them
        self.reopen()

    @property
    def path(self) -> str:
        """What to give pyserial: the link if there is one, else the slave's device path."""
        return str(self.link) if self.link is not None else self.slave_path

    @property
    def is_open(self) -> bool:
        return self._master is not None

    def reopen(self) -> None:
        """(Re)create the pty: a new slave device, the link pointing at it."""
        if self.closed:
            raise PtyClosed("pty closed")
        self.hangup()
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        with self._lock:
            self._master, self._slave = master, slave
            self.slave_path = os.ttyname(slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self.slave_path)
            os.replace(tmp, self.link)  # atomic: an opener sees the old or the new slave

    def hangup(self) -> None:
        """Close the pty (the other end sees the device vanish) and remove the link."""
        with self._lock:
            fds, self._master, self._slave = (self._master, self._slave), None, None
        if self.link is not None and self.link.is_symlink():
            self.link.unlink(missing_ok=True)
        for fd in fds:
            if fd is not None:
                os.close(fd)

    def close(self) -> None:
        self.hangup()
        self.closed = True

    # -- the pyserial-like part -----------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        """Bytes the other end wrote that :meth:`read` has not taken yet (0 while hung up)."""
        if self.closed:
            raise PtyClosed("pty closed")
        fd = self._master
        if fd is None:
            return 0
        try:
            return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:  # hung up meanwhile
            return 0

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes, as soon as there are any; waits at most ``timeout`` s;
        ``b""`` while hung up."""
        if self.closed:
            raise PtyClosed("pty closed")
        fd = self._master
        if fd is None:
            threading.Event().wait(self.timeout)
            return b""
        if size <= 0:
            return b""
        try:
            ready, _, _ = select.select([fd], [], [], self.timeout)
            return os.read(fd, size) if ready else b""
        except (BlockingIOError, ValueError):
            return b""
        except OSError as exc:
            if exc.errno in (errno.EBADF, errno.EIO):  # hung up meanwhile / nobody on the slave
                return b""
            raise

    def write(self, data: bytes) -> int:
        """Write what the pty takes now; bytes it cannot take (or while hung up) are dropped."""
        with self._lock:
            fd = self._master
            if fd is None:
                self.dropped += len(data)
                return 0
            try:
                n = os.write(fd, data)
            except (BlockingIOError, OSError):
                n = 0
        self.dropped += len(data) - n
        return n


__all__ = ["Pty", "PtyClosed"]
