#!/usr/bin/env python
"""``python scripts/sweep.py --help``: see ``trl_dgpq/commands/sweep.py``."""
import sys

from trl_dgpq.commands.sweep import main

if __name__ == "__main__":
    sys.exit(main())
