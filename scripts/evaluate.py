#!/usr/bin/env python
"""``python scripts/evaluate.py --help``: see ``trl_dgpq/commands/evaluate.py``."""
import sys

from trl_dgpq.commands.evaluate import main

if __name__ == "__main__":
    sys.exit(main())
