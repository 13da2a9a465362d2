"""``python -m hexbench`` = ``hexbench``."""

import sys

from .cli import main

sys.exit(main())
