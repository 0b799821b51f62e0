"""Answer ``--help`` and refuse an unknown flag before the heavy imports.

A command's parser is built from the config dataclasses of every env and agent, whose
modules import torch and tensordict: seconds before the first line, minutes' worth under
load for a typo. ``help.json`` beside this file holds each command's ``--help`` as it
prints at 100 columns (run as ``trl-dgpq NAME`` and as ``scripts/NAME.py``), written by
``python -m trl_dgpq.commands.early`` and checked against the live parsers by
tests/test_commands.py. From it, ``answer`` prints the help, or refuses a ``--flag`` that
no option of the command begins with, in one line and exit 2, importing nothing heavy;
anything else goes on to the command's own parser, which checks the rest.
"""
from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
import re
import sys
from pathlib import Path
from typing import List, Optional
from unittest import mock

HELP_FILE = Path(__file__).with_name("help.json")
COMMANDS = ("train", "evaluate", "plot", "report", "sweep", "reproduce", "tune")
WIDTH = "100"
CORES = 7919  # os.cpu_count() while the help is captured: sweep's and reproduce's defaults, filled in later
OPTION_LINE = re.compile(r"^ {1,8}(-.*?)(?:  |$)", re.M)  # an option's names, before its help column


def capture(name: str, entry: Optional[str], cores: int = CORES) -> str:
    """``NAME --help`` as the command prints it at 100 columns, run as ``entry`` ("trl-dgpq", or
    None for scripts/NAME.py), with ``os.cpu_count()`` returning ``cores``."""
    import trl_dgpq.commands as commands
    old_entry, old_columns = commands.ENTRY, os.environ.get("COLUMNS")
    commands.ENTRY, os.environ["COLUMNS"] = entry, WIDTH
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit), \
                mock.patch("os.cpu_count", return_value=cores):
            importlib.import_module(f"trl_dgpq.commands.{name}").main(["--help"])
    finally:
        commands.ENTRY = old_entry
        if old_columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old_columns
    return out.getvalue()


def snapshot() -> dict:
    """{command: {"trl-dgpq": help, "script": help}} from the live parsers."""
    return {name: {"trl-dgpq": capture(name, "trl-dgpq"), "script": capture(name, None)} for name in COMMANDS}


def options(help_text: str) -> List[str]:
    """The long options a help text lists."""
    return sorted({flag for m in OPTION_LINE.finditer(help_text) for flag in re.findall(r"--[\w-]+", m.group(1))})


def answer(name: str, argv: List[str]) -> Optional[int]:
    """The exit code if ``argv`` is answered here (help printed, or an unknown flag refused);
    None to run the command."""
    from trl_dgpq.commands import ENTRY, prog
    try:
        text = json.loads(HELP_FILE.read_text())[name]["trl-dgpq" if ENTRY else "script"]
    except (OSError, ValueError, KeyError):  # no snapshot: the command's own parser answers
        return None
    args = argv[:argv.index("--")] if "--" in argv else argv
    if "-h" in args or "--help" in args:
        sys.stdout.write(text.replace(str(CORES), str(os.cpu_count() or 1)))
        return 0
    known = options(text)
    unknown = [a for a in args if a.startswith("--") and not any(o.startswith(a.split("=")[0]) for o in known)]
    if unknown:  # argparse accepts an unambiguous prefix, so only a flag no option begins with is refused
        import difflib
        guesses = [g for a in unknown for g in difflib.get_close_matches(a.split("=")[0], known, n=1, cutoff=0.75)]
        hint = f"; did you mean {' '.join(dict.fromkeys(guesses))}?" if guesses else ""
        print(f"{prog(name)}: error: unrecognized arguments: {' '.join(unknown)}{hint} (see {prog(name)} --help)",
              file=sys.stderr)
        return 2
    return None


def main() -> int:
    HELP_FILE.write_text(json.dumps(snapshot(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {HELP_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
