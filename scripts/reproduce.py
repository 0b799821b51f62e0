#!/usr/bin/env python
"""``python scripts/reproduce.py --help``: see ``trl_dgpq/commands/reproduce.py``."""
import sys

from trl_dgpq.commands import run

if __name__ == "__main__":
    sys.exit(run("reproduce"))
