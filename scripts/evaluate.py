#!/usr/bin/env python
"""``python scripts/evaluate.py --help``: see ``trl_dgpq/commands/evaluate.py``."""
import sys

from trl_dgpq.commands import run

if __name__ == "__main__":
    sys.exit(run("evaluate"))
