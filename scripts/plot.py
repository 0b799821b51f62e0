#!/usr/bin/env python
"""``python scripts/plot.py --help``: see ``trl_dgpq/commands/plot.py``."""
import sys

from trl_dgpq.commands import run

if __name__ == "__main__":
    sys.exit(run("plot"))
