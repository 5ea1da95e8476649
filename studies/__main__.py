"""``python -m studies NAME ...``: the same as ``pmht-opt study NAME ...``."""

import sys

from studies.cli import main

sys.exit(main(prog="python -m studies"))
