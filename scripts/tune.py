#!/usr/bin/env python
"""``python scripts/tune.py --help``: see ``trl_dgpq/commands/tune.py``."""
import sys

from trl_dgpq.commands import run

if __name__ == "__main__":
    sys.exit(run("tune"))
