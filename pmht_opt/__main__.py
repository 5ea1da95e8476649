"""``python -m pmht_opt``: the ``pmht-opt`` command."""

import sys

from pmht_opt.cli import main

if __name__ == "__main__":
    sys.exit(main())
