#!/usr/bin/env python
"""``python scripts/plot.py --help``: see ``trl_dgpq/commands/plot.py``."""
import sys

from trl_dgpq.commands.plot import main

if __name__ == "__main__":
    sys.exit(main())
