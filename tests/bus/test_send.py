"""``hexbench send``, like cansend: one command to a fleet running in another process."""

from __future__ import annotations

import os

from hexbench.cli import main
from processes import free_port, wall_fleet


def test_send_to_a_running_fleet(capsys):
    port = free_port()
    fleet = f"send{os.getpid()}"
    proc = wall_fleet("pair", port, fleet, seconds=90)
    bus = ["--connect", f"tcp/127.0.0.1:{port}", "--fleet", fleet]
    try:
        # the modules boot for about 8 s: Select until module 1 answers
        for _ in range(10):
            if main(["send", "SxP", "3", "--select", "1", "--timeout", "2", *bus]) == 0:
                break
        out = capsys.readouterr().out
        assert "ack" in out and "byte=11 meaning='SxP'" in out.splitlines()[-1]
        assert main(["send", "7", "--select", "2", *bus]) == 1  # 'N': unknown code
        assert "unknown code" in capsys.readouterr().out
        assert main(["send", "MCW", "4", "8", *bus]) == 2
        assert "missing t2, t3" in capsys.readouterr().err
        # after a Select only the selected module answers; a broadcast is answered by nobody
        assert main(["send", "Select", "0", "0", "0", "--timeout", "2", *bus]) == 3
    finally:
        proc.terminate()
        proc.communicate(timeout=30)
    assert main(["send", "LOn", "--timeout", "1", "--fleet", f"{fleet}-nobody", "--isolated"]) == 3
    assert "no fleet or bridge listens" in capsys.readouterr().err
