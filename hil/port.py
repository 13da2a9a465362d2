"""Serial ports by pyserial URL that may disappear and come back.

:class:`LivePort` owns one port: a reader thread hands every chunk of bytes to a
callback with its arrival time, a writer thread sends queued bytes (so the caller never
blocks on a slow line), and when the port disappears (USB cable pulled, pty closed,
socket dropped) it reports a fault, retries with exponential backoff and reports the
recovery. Any URL :func:`serial.serial_for_url` accepts works: ``/dev/ttyUSB0``,
``socket://host:port`` (ser2net raw), ``rfc2217://host:port`` (ser2net telnet), ``loop://``.
"""

from __future__ import annotations

import os
import queue
import re
import threading
import time
from dataclasses import dataclass
from typing import Callable

import serial

#: Errors that mean "the port is gone" (pyserial wraps most, ``in_waiting`` raises OSError).
PORT_ERRORS = (serial.SerialException, OSError)


def open_port(url: str, baud: int, *, timeout_s: float = 0.05) -> serial.SerialBase:
    """Open ``url`` 8N1 at ``baud`` with a short read timeout.

    Raises :class:`serial.SerialException` if the port cannot be opened and
    :class:`ValueError` for a malformed URL or an unknown URL scheme (both from pyserial).
    """
    return serial.serial_for_url(url, baudrate=baud, bytesize=serial.EIGHTBITS,
                                 parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                                 timeout=timeout_s, write_timeout=None)


def port_name(url: str) -> str:
    """A short key-safe name for a port: ``/dev/ttyUSB0`` -> ``ttyUSB0``,
    ``socket://10.0.0.5:7000`` -> ``socket-10.0.0.5:7000``, ``loop://`` -> ``loop``."""
    if "://" in url:
        scheme, _, rest = url.partition("://")
        rest = rest.split("?", 1)[0].strip("/")
        name = f"{scheme}-{rest}" if rest else scheme
    else:
        name = os.path.basename(url.rstrip("/")) or url
    return re.sub(r"[^A-Za-z0-9_.:+=-]", "_", name)


def port_identity(url: str) -> str:
    """Which device is behind ``url`` now: for a local device, the path it resolves to, its
    device number and inode, and a USB adapter's serial number; for a
    network URL (``socket://``, ``rfc2217://``, ``loop://``), the URL: nothing to check there."""
    if "://" in url:
        return url
    try:
        real = os.path.realpath(url)
        st = os.stat(real)
    except OSError as exc:
        return f"{url}: {exc.strerror or exc}"
    ident = f"{real} (device {os.major(st.st_rdev)}:{os.minor(st.st_rdev)}, inode {st.st_ino})"
    serial_no = _usb_serial(real)
    return ident + (f", USB serial {serial_no}" if serial_no else "")


def _usb_serial(device: str) -> str | None:
    """The serial number a USB adapter reports, from sysfs (Linux), if there is one."""
    node = f"/sys/class/tty/{os.path.basename(device)}/device"
    for up in ("..", "../..", "../../.."):
        try:
            with open(os.path.join(node, up, "serial"), encoding="ascii", errors="replace") as f:
                return f.read().strip() or None
        except OSError:
            continue
    return None


@dataclass(frozen=True)
class Backoff:
    """Retry delays: ``first_s``, doubling up to ``max_s``."""

    first_s: float = 0.05
    max_s: float = 2.0

    def delays(self):
        d = self.first_s
        while True:
            yield d
            d = min(d * 2, self.max_s)


class LivePort:
    """A serial port that survives disappearing.

    Callbacks run on the port's threads; a bus participant posts them to its clock:

    * ``on_data(data, t_ns)``: bytes read, ``t_ns`` = ``now_ns()`` when they arrived;
    * ``on_fault(error)``: the port disappeared (``error`` is pyserial's/the OS's message);
      called after the last ``on_data`` of the old connection;
    * ``on_recover(down_s, attempts)``: the port is open again (``identity`` says which
      device it is now, ``first_identity`` which it was when first opened: a replug may
      bring back another device under the same name);
    * ``on_tx_lost(data, reason)``: bytes that could not be sent (port down or write failed).

    :meth:`open` opens the port the first time and raises what pyserial raises, so a typo
    in a URL is an error at once; from then on the port is retried for as long as it runs.
    """

    def __init__(self, url: str, baud: int, *, on_data: Callable[[bytes, int], None],
                 on_fault: Callable[[str], None] = lambda error: None,
                 on_recover: Callable[[float, int], None] = lambda down_s, attempts: None,
                 on_tx_lost: Callable[[bytes, str], None] = lambda data, reason: None,
                 now_ns: Callable[[], int] = time.monotonic_ns, backoff: Backoff = Backoff(),
                 opener: Callable[[str, int], serial.SerialBase] = open_port) -> None:
        self.url = url
        self.baud = baud
        self.on_data = on_data
        self.on_fault = on_fault
        self.on_recover = on_recover
        self.on_tx_lost = on_tx_lost
        self.now_ns = now_ns
        self.backoff = backoff
        self._opener = opener
        self._port: serial.SerialBase | None = None
        self._closing = threading.Event()
        self._tx: queue.Queue[bytes | None] = queue.Queue()
        self._threads: list[threading.Thread] = []
        self.bytes_in = 0
        self.bytes_out = 0
        self.faults = 0
        self.recoveries = 0
        self.identity: str | None = None  # port_identity() at the last open
        self.first_identity: str | None = None

    @property
    def connected(self) -> bool:
        return self._port is not None

    def open(self, *, wait: bool = False) -> "LivePort":
        """Open the port and start the reader and writer threads.

        Raises what pyserial raises if the port cannot be opened; with ``wait``, a port that
        is not there yet is reported through ``on_fault`` and retried like a lost one."""
        try:
            self._port = self._opener(self.url, self.baud)
            self.identity = self.first_identity = port_identity(self.url)
        except PORT_ERRORS as exc:
            if not wait:
                raise
            self.faults += 1
            self.on_fault(str(exc) or type(exc).__name__)
        for target, what in ((self._read_loop, "read"), (self._write_loop, "write")):
            t = threading.Thread(target=target, name=f"hil-{what}-{port_name(self.url)}", daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def write(self, data: bytes) -> None:
        """Queue bytes for the line (thread-safe, never blocks)."""
        if data:
            self._tx.put(bytes(data))

    def close(self) -> None:
        """Stop the threads (a read in progress ends within the read timeout), close the port."""
        self._closing.set()
        self._tx.put(None)
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except PORT_ERRORS:
                pass

    # -- threads ----------------------------------------------------------------------------
    def _read_loop(self) -> None:
        while not self._closing.is_set():
            port = self._port
            if port is None:
                self._reconnect()
                continue
            try:
                data = port.read(port.in_waiting or 1)
            except PORT_ERRORS as exc:
                if self._closing.is_set():
                    return
                self._lost(port, exc)
                continue
            if data:
                self.bytes_in += len(data)
                self.on_data(data, self.now_ns())

    def _lost(self, port: serial.SerialBase, exc: BaseException) -> None:
        self._port = None
        try:
            port.close()
        except PORT_ERRORS:
            pass
        self.faults += 1
        self.on_fault(str(exc) or type(exc).__name__)

    def _reconnect(self) -> None:
        down_at = time.monotonic()
        for attempts, delay in enumerate(self.backoff.delays(), 1):
            if self._closing.wait(delay):
                return
            try:
                port = self._opener(self.url, self.baud)
            except PORT_ERRORS:
                continue
            if self._closing.is_set():
                port.close()
                return
            self._port = port
            self.identity = port_identity(self.url)
            if self.first_identity is None:
                self.first_identity = self.identity
            self.recoveries += 1
            self.on_recover(time.monotonic() - down_at, attempts)
            return

    def _write_loop(self) -> None:
        while True:
            data = self._tx.get()
            if data is None or self._closing.is_set():
                return
            port = self._port
            if port is None:
                self.on_tx_lost(data, f"port {self.url} is down")
                continue
            try:
                port.write(data)
                self.bytes_out += len(data)
            except PORT_ERRORS as exc:  # the reader notices the port is gone and reports it
                self.on_tx_lost(data, f"write to {self.url} failed: {exc}")


__all__ = ["Backoff", "LivePort", "PORT_ERRORS", "open_port", "port_identity", "port_name"]
