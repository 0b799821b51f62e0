#!/usr/bin/env python
"""``python scripts/sweep.py --help``: see ``trl_dgpq/commands/sweep.py``."""
import sys

from trl_dgpq.commands import run

if __name__ == "__main__":
    sys.exit(run("sweep"))
