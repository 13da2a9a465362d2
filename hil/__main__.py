"""``python -m hil`` = ``hexbench hil``."""

import sys

from bus.cli import main

sys.exit(main(["hil", *sys.argv[1:]]))
