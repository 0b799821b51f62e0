"""``trl-dgpq COMMAND ...`` (installed by pip) and ``python -m trl_dgpq COMMAND ...``: one
entry point with a subcommand per script, as ``git`` or ``ray`` have; ``python
scripts/COMMAND.py`` runs the same code from a checkout."""
from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "train": "train one experiment (many seeds, batched in one process)",
    "sweep": "many experiments on a pool of processes or a Ray cluster",
    "evaluate": "a trained run's agents on new episodes, exploration off (eval.csv)",
    "plot": "figures of one or more run folders",
    "report": "learners compared by environment steps, from run folders",
    "reproduce": "every experiment of the reproduction, then REPORT.md",
    "tune": "an agent's settings tuned by Optuna on one env, every trial the same budget",
}


def usage() -> str:
    from trl_dgpq import __version__
    lines = [f"usage: trl-dgpq COMMAND [--help] ...   (trl-dgpq {__version__})", "", "commands:"]
    lines += [f"  {name:<10} {text}" for name, text in COMMANDS.items()]
    return "\n".join(lines + ["", "trl-dgpq COMMAND --help shows a command's options."])


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    if argv[0] == "--version":
        from trl_dgpq import __version__
        print(f"trl-dgpq {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"trl-dgpq: unknown command {name!r}; one of {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    import trl_dgpq.commands
    trl_dgpq.commands.ENTRY = "trl-dgpq"
    return trl_dgpq.commands.run(name, rest)


if __name__ == "__main__":
    sys.exit(main())
