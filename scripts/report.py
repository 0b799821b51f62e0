#!/usr/bin/env python
"""``python scripts/report.py --help``: see ``trl_dgpq/commands/report.py``."""
import sys

from trl_dgpq.commands import run

if __name__ == "__main__":
    sys.exit(run("report"))
