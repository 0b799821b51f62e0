#!/usr/bin/env python
"""Write each command's ``--help`` into docs/commands.md, between its markers
``<!-- help: NAME -->`` and ``<!-- /help -->``, and into trl_dgpq/commands/help.json (what
``--help`` prints before the heavy imports); and the published reproduction's summary
(results/report/summary.md, written from its data) into README.md between
``<!-- results: ... -->`` and ``<!-- /results -->``. ``--check`` only says whether they are up
to date (tests/test_docs.py runs that check, tests/test_commands.py the JSON's, in ``make test``).

    python scripts/docs_reference.py            # after changing a command's options
    python scripts/docs_reference.py --check    # exit 1 and name the commands out of date
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "commands.md"
COMMANDS = ("train", "evaluate", "plot", "report", "sweep", "reproduce", "tune")
CORES = 2      # sweep's and reproduce's --workers default to the machine's cores: shown as N
BLOCK = re.compile(r"(<!-- help: (\w+) -->\n)(.*?)(<!-- /help -->)", re.S)
README, SUMMARY = ROOT / "README.md", ROOT / "results" / "report" / "summary.md"
RESULTS = re.compile(r"(<!-- results: .*? -->\n)(.*?)(<!-- /results -->)", re.S)


def with_summary(readme: str) -> str:
    """README.md with its results block replaced by the published summary (unchanged without one)."""
    if not SUMMARY.is_file():
        return readme
    return RESULTS.sub(lambda m: m.group(1) + SUMMARY.read_text().rstrip() + "\n" + m.group(3), readme)


def help_text(name: str) -> str:
    """``trl-dgpq NAME --help`` as the installed command prints it, at a fixed width."""
    sys.path.insert(0, str(ROOT))
    from trl_dgpq.commands.early import capture
    return capture(name, "trl-dgpq", cores=CORES).rstrip().replace(f"the cores, {CORES})", "the cores, N)") + "\n"


def render(page: str) -> str:
    """The page with every help block regenerated."""
    def block(m):
        return f"{m.group(1)}```text\n{help_text(m.group(2))}```\n{m.group(4)}"
    return BLOCK.sub(block, page)


def stale(page: str) -> list:
    """The commands whose block differs from their ``--help`` (or that have no block)."""
    blocks = {m.group(2): m.group(3) for m in BLOCK.finditer(page)}
    return [n for n in COMMANDS if blocks.get(n) != f"```text\n{help_text(n)}```\n"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="docs_reference.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--check", action="store_true", help="change nothing; exit 1 if the page is out of date")
    args = p.parse_args(argv)
    page = PAGE.read_text()
    readme = README.read_text()
    if args.check:
        out = stale(page)
        if out:
            print(f"{PAGE.relative_to(ROOT)}: out of date for {', '.join(out)}; run python scripts/docs_reference.py",
                  file=sys.stderr)
        if with_summary(readme) != readme:
            print(f"README.md: its results block is not {SUMMARY.relative_to(ROOT)}; run python "
                  "scripts/docs_reference.py", file=sys.stderr)
        return 1 if out or with_summary(readme) != readme else 0
    PAGE.write_text(render(page))
    README.write_text(with_summary(readme))
    from trl_dgpq.commands import early  # the same texts, answered before torch is imported
    early.main()
    return 0


if __name__ == "__main__":
    sys.exit(main())
