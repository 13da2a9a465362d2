"""Firmware in the loop: the C programs of ``firmware/`` in simavr, as a fleet member.

``firmware/build/hexbot-simavr`` (built by ``make -C firmware``) runs both ATmega162 images
of one module on our own ATmega162 core for libsimavr, wires their UART0s together and
exposes the comm board's centre IR channel and the control board's debug UART1 as
pseudo-terminals. To the rest of hexbench it is then a real module behind two serial
ports: :class:`FirmwareModule` starts it and says where those ports are.

:func:`run_fast` runs the same harness without ptys and without real-time pacing against a
byte script, and returns its log in :mod:`module_sim.script`'s format, so the C programs
and the Python model can be compared event by event.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import threading
from pathlib import Path

from bus.cheader import BUILD_DIR, FirmwareError, build_path, ensure_built

HARNESS = BUILD_DIR / "hexbot-simavr"

__all__ = ["FirmwareError", "FirmwareModule", "ensure_built", "images", "run_fast"]


def images(profile: str) -> tuple[Path, Path]:
    """(comm, control) ELF images of ``profile``."""
    return build_path("elf", "comm", profile), build_path("elf", "control", profile)


def _command(profile: str, *, dip: int, switches: int) -> list[str]:
    comm, control = images(profile)
    return [str(HARNESS), "--comm", str(comm), "--control", str(control),
            "--dip", str(dip), "--switches", str(switches)]


class FirmwareModule:
    """One module running the C firmware in simavr, in real time, behind two ptys.

    ``ir_path`` is its centre IR transceiver (300 baud), ``debug_path`` its control
    board's debug UART1 (4800 baud): give them to a bridge like a real board's ports.
    ``hold``: power up only when something has opened ``ir_path`` (so its boot banners
    are seen from the first byte). ``switches``: the optical switches, bit k-1 = side k.
    ``ir_link``/``debug_link``: where the pty symlinks go (default: a private directory).
    """

    def __init__(self, module_id: int, profile: str = "v2", *, switches: int = 0,
                 link_dir: str | os.PathLike[str] | None = None, hold: bool = False,
                 ir_link: str | None = None, debug_link: str | None = None) -> None:
        self.module_id = module_id
        self.profile = profile
        self._own_dir = link_dir is None
        self.dir = Path(link_dir) if link_dir is not None else Path(tempfile.mkdtemp(prefix="hexbot-fw"))
        self.ir_path = ir_link or str(self.dir / f"m{module_id}-ir")
        self.debug_path = debug_link or str(self.dir / f"m{module_id}-debug")
        self._cmd = _command(profile, dip=module_id, switches=switches) + [
            "--ir-link", self.ir_path, "--debug-link", self.debug_path] + (["--hold"] if hold else [])
        self.proc: subprocess.Popen[str] | None = None

    def start(self, timeout_s: float = 10.0) -> "FirmwareModule":
        """Start the harness and wait until its ptys exist."""
        ensure_built()
        self.proc = subprocess.Popen(self._cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, start_new_session=True)
        ready: list[str] = []
        reader = threading.Thread(target=lambda: ready.append(self.proc.stdout.readline()),  # type: ignore[union-attr]
                                  daemon=True)
        reader.start()
        reader.join(timeout_s)
        line = ready[0] if ready else ""
        if not line.startswith("hexbot-simavr:"):
            err = ""
            if self.proc.poll() is not None:
                err = (self.proc.stderr.read() if self.proc.stderr else "").strip()
            self.close()
            raise FirmwareError(f"firmware module m{self.module_id}: the simavr harness did not "
                                f"start: {err or 'no ready line within %g s' % timeout_s}")
        return self

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None:
            for stream in (self.proc.stdout, self.proc.stderr):
                if stream is not None:
                    stream.close()
        if self._own_dir:
            shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> "FirmwareModule":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def run_fast(script_text: str, seconds: float, *, profile: str = "v2", module_id: int = 1,
             switches: int = 0) -> list[str]:
    """Run the firmware against a byte script (:func:`module_sim.script.format_script`) as
    fast as simavr goes and return its log lines (``<time_ns> <what> <detail>``)."""
    ensure_built()
    with tempfile.TemporaryDirectory(prefix="hexbot-fw") as tmp:
        script = Path(tmp) / "script.txt"
        log = Path(tmp) / "log.txt"
        script.write_text(script_text)
        cmd = _command(profile, dip=module_id, switches=switches) + [
            "--fast", "--ir-script", str(script), "--log", str(log), "--seconds", f"{seconds:g}"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise FirmwareError(f"hexbot-simavr exited {r.returncode}: {r.stderr.strip()}")
        return log.read_text().splitlines()
