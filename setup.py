"""The C firmware's host libraries go into the wheel (``bus/_firmware/``), with the fleet core
that runs them (``module_sim/core/build/``): a non-editable
install (pip, pipx, a CI image) has no checkout beside it, and ``--program firmware`` runs
them (module_sim/firmware.py). They need only a C compiler, not the AVR toolchain; without
one the install goes on and ``--program firmware`` says what is missing. Everything else is
in pyproject.toml."""

import shutil
import subprocess
import sys
from pathlib import Path

from setuptools import Distribution, setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
LIBS = [f"libhexbot-{board}-{tag}.so" for board in ("comm", "control") for tag in ("v2", "thesis")]
CORE = "libhexcore.so"


class BuildPyWithFirmware(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install runs the checkout's firmware/build
        missing = [tool for tool in ("make", "cc", "ld", "objcopy") if shutil.which(tool) is None]
        if missing:
            print(f"hexbench: {', '.join(missing)} not found: the firmware's host libraries are not "
                  "built, and --program firmware will not run (apt-get install build-essential, "
                  "then install hexbench again)", file=sys.stderr)
            return
        subprocess.run(["make", "-s", "-C", str(HERE / "firmware"), "host", f"PYTHON={sys.executable}"],
                       check=True)
        dest = Path(self.build_lib) / "bus" / "_firmware"
        dest.mkdir(parents=True, exist_ok=True)
        for lib in LIBS:
            shutil.copy2(HERE / "firmware" / "build" / lib, dest / lib)
        # the fleet core (module_sim/core), which loads those libraries
        subprocess.run(["make", "-s", "-C", str(HERE / "module_sim" / "core")], check=True)
        core = Path(self.build_lib) / "module_sim" / "core" / "build"
        core.mkdir(parents=True, exist_ok=True)
        shutil.copy2(HERE / "module_sim" / "core" / "build" / CORE, core / CORE)


class BinaryDistribution(Distribution):
    """The wheel holds shared libraries for this platform: not a pure-Python wheel."""

    def has_ext_modules(self) -> bool:
        return True


setup(cmdclass={"build_py": BuildPyWithFirmware}, distclass=BinaryDistribution)
