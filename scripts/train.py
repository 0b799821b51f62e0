#!/usr/bin/env python
"""``python scripts/train.py --help``: see ``trl_dgpq/commands/train.py``."""
import sys

from trl_dgpq.commands import run

if __name__ == "__main__":
    sys.exit(run("train"))
