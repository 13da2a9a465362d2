"""hexbench hil: real HexBot hardware on the bus.

* :mod:`hil.bridge` — :class:`~hil.bridge.CentreBridge` (the PC's central IR transceiver on
  a serial port) and :class:`~hil.bridge.DebugBridge` (a module's debug UART1);
* :mod:`hil.port` — serial ports by pyserial URL that may disappear and come back;
* :mod:`hexbench.standin` — a virtual module behind a pty or serial URL, a stand-in for hardware;
* :mod:`hil.pty` — pseudo-terminals with a stable name.

``hexbench hil --port URL`` and ``hexbench standin --pty``; see docs/hil.md.
"""
